"""What a run reports of its timing and counts, from the figures the schedulers wrote."""

from __future__ import annotations

import time
from collections import Counter

import numpy as np
import pytest

from hub.protocol import Description
from hub.report import LoopTimes, counts, steps_share


def test_timing_covers_the_steps_done_only():
    times = LoopTimes.for_run("realtime", 10.0, n_steps=100)
    times.start()
    times.step_wall_s[:4] = [0.001, 0.002, 0.003, 0.004]
    times.lateness_s[:4] = [0.0, 0.0, 0.0005, 0.004]
    times.late_steps = 1
    out = times.report(steps=4, scheduling=None)
    assert out["steps"] == 4 and out["late_share"] == 0.25
    assert out["step_ms_median"] == pytest.approx(2.5)
    assert out["lateness_ms_max"] == pytest.approx(4.0)
    assert out["mode"] == "realtime" and out["wall_s"] > 0


def test_wall_and_cpu_time_end_with_the_steps_not_with_what_the_hub_does_after_them():
    times = LoopTimes.for_run("lockstep", 10.0, n_steps=100)
    times.start()
    times.stop()
    out = times.report(steps=100, scheduling=None)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 0.01:  # the hub closing up: a final stop, counters
        pass
    later = times.report(steps=100, scheduling=None)
    assert later["wall_s"] == out["wall_s"] < 0.01
    assert later["hub_cpu_s"] == out["hub_cpu_s"] < 0.01
    assert later["steps_per_s"] == out["steps_per_s"]
    times.stop()  # once only
    assert times.report(steps=100, scheduling=None)["wall_s"] == out["wall_s"]


def test_realtime_steps_end_with_the_last_steps_period():
    times = LoopTimes.for_run("realtime", 10.0, n_steps=4)
    times.lateness_s[:] = 0.0  # each step started on time
    times.start()
    times.stop(not_before=times.t_start + 0.04)  # the 4th period ends 40 ms after the 1st began
    out = times.report(steps=4, scheduling=None)
    assert out["wall_s"] == pytest.approx(0.04) and out["x_realtime"] == pytest.approx(1.0)


def test_time_paused_is_wall_time_but_not_the_runs_pace(monkeypatch):
    clock = [100.0]
    monkeypatch.setattr(time, "monotonic", lambda: clock[0])
    times = LoopTimes.for_run("realtime", 10.0, n_steps=400)
    times.lateness_s[:200] = 0.0
    times.start()
    clock[0] += 1.0  # 100 steps on time
    times.pause()
    clock[0] += 3.0  # paused (ctl, the dashboard)
    times.resume()
    clock[0] += 1.0  # 100 steps more
    times.pause()
    clock[0] += 2.0  # paused again, and stopped so
    times.stop()
    out = times.report(steps=200, scheduling=None)
    assert out["wall_s"] == pytest.approx(7.0) and out["paused_s"] == pytest.approx(5.0)
    assert out["x_realtime"] == pytest.approx(1.0) and out["steps_per_s"] == pytest.approx(100)
    assert times.paused_s == pytest.approx(5.0)  # the pause under way ended with the steps


def test_a_run_that_never_stepped_reports_zeros():
    out = LoopTimes.for_run("lockstep", 10.0, 10).report(steps=0, scheduling=None)
    assert out["steps"] == out["steps_per_s"] == out["hub_cpu_s"] == 0
    assert "step_ms_median" not in out and "lateness_ms_max" not in out


def test_counts_give_missing_steps_by_role_and_drops_by_kind():
    out = counts(
        None, Counter(body=2), {"body": {3, 4}, "culture": set()}, {"culture": Counter(foreign=5)}
    )
    assert out["late"] == {"body": 2} and out["missing"] == {"body": 2}
    assert (
        out["dropped"] == {"culture": {"foreign": 5}} and out["single_channel_bursts_online"] == 0
    )


def test_an_endpoints_cpu_time_is_that_of_the_steps_alone():
    desc = Description(
        role="culture",
        id="0",
        kind="t",
        channel=np.arange(2),
        x_um=np.zeros(2),
        y_um=np.zeros(2),
        counters={"cpu_s": 1.5},
    )
    out = steps_share(desc, {"culture": {"cpu_s": 4.0, "steps": 10}})
    assert out == {"cpu_s": 2.5, "steps": 10}
