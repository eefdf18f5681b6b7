"""The figures a benchmark derives from its runs (no run here: hand-built inputs)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench.closed_loop import (
    PageClient,
    _dashboard_cpu_s,
    _frame_step,
    _loop_cpu_s,
    _realtime_figures,
    paired_cost,
)
from bench.loop_ab import run_order
from bench.page import browser_cpu_s

BENCH = Path(__file__).resolve().parent.parent / "bench"


def test_equal_pairs_give_their_cost_with_no_spread():
    cost, lo, hi = paired_cost([0.9] * 8)
    assert cost == pytest.approx(0.1)
    assert lo == pytest.approx(0.1) and hi == pytest.approx(0.1)


def test_the_interval_holds_the_median_cost_and_widens_with_the_spread():
    narrow = paired_cost([0.92, 0.93, 0.94, 0.93, 0.92, 0.94])
    wide = paired_cost([0.80, 0.99, 0.85, 1.02, 0.88, 0.97])
    for cost, lo, hi in (narrow, wide):
        assert lo <= cost <= hi
    assert wide[2] - wide[1] > narrow[2] - narrow[1]
    assert narrow[0] == pytest.approx(1 - 0.93)


def test_a_faster_run_with_the_dashboard_is_a_negative_cost():
    cost, _, hi = paired_cost([1.05, 1.04, 1.06])
    assert cost < 0 and hi < 0


def test_the_bench_page_reads_the_step_a_frame_shows_and_nothing_else():
    from dashboard.server import page_json

    frame = {"type": "frame", "generation": 2, "reset": False, "t_s": 1.5, "step": 150}
    assert _frame_step(page_json({**frame, "spikes": {"n": 0}})) == 150
    assert _frame_step(page_json({**frame, "step": -1})) == -1
    assert _frame_step(page_json({"type": "scene", "scene": {"step": 3}})) is None
    assert _frame_step(page_json({"type": "reply", "cmd": "pause", "ok": True})) is None


def test_the_bench_page_times_the_longest_its_step_stood_still_between_two_moves():
    page = PageClient.__new__(PageClient)  # its bookkeeping only: no websocket
    page.step, page.moved_at, page.still_s_max = -1, 0.0, 0.0
    for now, step in [(0.0, -1), (1.0, 5), (1.1, 9), (1.2, 9), (2.6, 9), (2.7, 30), (2.8, 20)]:
        page._saw(step, now)
    assert page.step == 30 and page.still_s_max == pytest.approx(1.6)  # 9 from 1.1 s to 2.7 s
    page._saw(30, 9.0)  # still at the end: counted by the run's last step, not here
    assert page.still_s_max == pytest.approx(1.6)


def test_a_realtime_ab_reports_each_sides_late_steps_lateness_and_replies(capsys):
    def run(late_steps, p99_ms, max_ms, late, missing):
        timing = {"late_steps": late_steps, "lateness_ms_p99": p99_ms, "lateness_ms_max": max_ms}
        return timing, {"late": late, "missing": missing}

    timings = {
        "A": [run(0, 0.10, 0.5, {}, {}), run(1, 0.30, 2.5, {"culture": 1}, {})],
        "B": [run(2, 0.20, 1.5, {"body": 1}, {"culture": 2}), run(0, 0.40, 0.9, {}, {})],
    }
    out = _realtime_figures(timings, [30.1, 29.9], [0.1, 0.2], 0, 0.0, 30.0)
    assert out["dashboard_rt_late_steps"] == {"A": 1, "B": 2}
    assert out["dashboard_rt_p99_lateness_ms"] == {"A": 0.2, "B": 0.3}
    assert out["dashboard_rt_max_lateness_ms"] == {"A": 2.5, "B": 1.5}
    assert out["dashboard_rt_runs"]["B"]["late_replies"] == [1, 0]
    assert out["dashboard_rt_runs"]["B"]["missing_replies"] == [2, 0]
    said = capsys.readouterr().out
    assert "without the dashboard: late steps [0, 1]" in said
    assert "with the dashboard: late steps [2, 0]" in said


def test_the_loops_cpu_is_the_hub_its_endpoints_and_the_burst_observer():
    manifest = {
        "timing": {"hub_cpu_s": 2.0, "steps": 1000},
        "endpoints": {"body": {"cpu_s": 0.5}, "culture": {"cpu_s": 1.5}},
        "counts": {"online_observer_cpu_s": 0.25},
    }
    assert _loop_cpu_s(manifest) == pytest.approx(4.25)
    del manifest["counts"]  # live analysis off
    assert _loop_cpu_s(manifest) == pytest.approx(4.0)


def test_the_dashboards_cpu_is_read_from_the_first_step_it_showed():
    log = (
        "2026-11-28 02:00:00,000 dashboard.server INFO: served 300 ticks in 10.0 s; the "
        "dashboard's process used 1.50 s of CPU (15.0 % of a core)\n"
        "2026-11-28 02:00:00,001 dashboard.server INFO: from the first step shown: 0.42 s of "
        "CPU in 8.0 s (5.2 % of a core)\n"
    )
    assert _dashboard_cpu_s(log) == pytest.approx(0.42)
    assert _dashboard_cpu_s("no step was shown") is None


def test_the_browsers_cpu_is_that_of_the_named_processes_under_this_one():
    busy = subprocess.Popen(["sh", "-c", "while :; do :; done"])
    try:
        deadline = time.monotonic() + 30.0
        while browser_cpu_s(os.getpid(), "sh") < 0.2:
            assert time.monotonic() < deadline, "a busy child's CPU time was not counted"
            time.sleep(0.05)
        assert browser_cpu_s(os.getpid(), "no-such-name") == 0.0
        assert browser_cpu_s(busy.pid, "sh") >= 0.2  # the root itself counts
        assert browser_cpu_s(busy.pid, "python") == 0.0  # this process is not under it
    finally:
        busy.kill()
        busy.wait()


@pytest.mark.parametrize("names", [list("ab"), list("abc"), list("abcd")])
def test_an_ab_runs_each_side_as_often_at_each_place_in_a_round(names):
    rounds = [run_order(names, i) for i in range(2 * len(names))]
    assert all(sorted(order) == names for order in rounds)
    for place in range(len(names)):
        at_place = [order[place] for order in rounds]
        assert all(at_place.count(name) == 2 for name in names)


def test_a_window_counts_the_steps_completed_from_its_start_up_to_its_end():
    from bench.dashboard_within import Window, steps_in

    w = Window("without", os.getpid())
    w.t0_ns, w.t1_ns = 1_000, 2_000
    assert steps_in([999, 1_000, 1_500, 1_999, 2_000, 2_500], w) == 3


def test_a_window_measures_the_cpu_a_process_used_over_it():
    from bench.dashboard_within import Window

    with Window("with", os.getpid(), os.getpid()) as w:
        end = time.process_time() + 0.2
        while time.process_time() < end:
            pass
    assert 0.1 <= w.hub_cpu_s <= 1.0 and 0.1 <= w.dashboard_cpu_s <= 1.0
    assert w.seconds >= 0.15 and w.hub_faults >= 0


def test_a_toggled_cost_pools_every_window_of_each_kind():
    from bench.dashboard_toggle import pooled_cost

    # steps and seconds per pair, without then with: 10 % fewer steps with, at any pace
    steps = [[100, 90], [200, 180], [50, 45], [120, 108]]
    spans = [[0.5, 0.5]] * 4
    cost, lo, hi = pooled_cost(steps, spans)
    assert cost == pytest.approx(0.10) and lo == pytest.approx(0.10) and hi == pytest.approx(0.10)
    # a window's pace counts by its length, and a faster loop with is a negative cost
    cost, lo, hi = pooled_cost([[100, 330], [100, 110]], [[1.0, 3.0], [1.0, 1.0]])
    assert cost == pytest.approx(1 - (440 / 4) / (200 / 2))
    assert lo <= cost <= hi


def test_a_toggled_page_says_how_many_frames_it_took_when_asked_and_at_its_end():
    from hub.bus import free_tcp_port

    # no dashboard there: the page keeps trying to connect, and has taken no frame
    page = subprocess.Popen(
        [sys.executable, str(BENCH / "dashboard_toggle.py"), "--page-port", str(free_tcp_port())],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert json.loads(page.stdout.readline()) == {"frames": 0, "bytes": 0}  # ready
        page.send_signal(signal.SIGUSR1)
        assert json.loads(page.stdout.readline())["frames"] == 0
        page.send_signal(signal.SIGSTOP)
        page.send_signal(signal.SIGCONT)
        page.terminate()
        out, _ = page.communicate(timeout=10)
    finally:
        page.kill()
    assert json.loads(out.strip().splitlines()[-1])["frames"] == 0
    assert page.returncode == 0


def test_a_freeze_reports_the_steps_in_each_half_and_its_longest_gap():
    from bench.dashboard_freeze import longest_gaps

    ms = 1_000_000
    steps = [0, 10 * ms, 20 * ms, 700 * ms, 710 * ms, 1_600 * ms, 1_610 * ms]
    (row,) = longest_gaps(steps, [(0, 1_000 * ms, 2_000 * ms)])
    assert row == {
        "steps_frozen": 5, "steps_running": 2, "gap_ms": 890.0, "gap_from_ms": 710,
        "gap_to_ms": 1600,
    }  # fmt: skip


def test_the_dashboards_data_path_takes_every_view_of_a_recorded_run(tmp_path):
    from bench.dashboard import measure, steps_of
    from tests.dashboard.synthetic import write_run

    write_run(tmp_path)
    steps, scene = steps_of(tmp_path)
    figures = measure(steps, scene, steps_per_view=10)  # exits if the dashboard dropped one
    assert figures["views"] == len(steps) // 10
    assert figures["view_bytes"] > 0 and figures["frame_bytes"] > 0
    assert set(figures["cpu_s"]) == {"hub_took_sent", "hub_view", "dashboard_take", "page_frame"}


def test_the_wake_floor_bench_times_each_way_of_waiting_and_ends_with_its_json(capsys):
    from bench.wake_floor import main

    out = main(["--period-ms", "1", "--wakes", "200", "--rounds", "2"])
    last = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert last == json.loads(json.dumps(out))
    assert len(out["rounds"]) == 2 and all(set(r) == {"queue", "sleep"} for r in out["rounds"])
    for how in ("queue", "sleep"):
        assert 0.0 <= out[f"wake_late_share_{how}"] <= 1.0
    assert out["wake_max_ms_queue"] >= out["wake_p99_ms_queue"] >= 0.0
