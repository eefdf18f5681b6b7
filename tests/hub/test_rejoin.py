"""An endpoint that vanishes and comes back within ``policy.rejoin_s`` rejoins the run.

Real processes: the body is SIGKILLed mid-run and a new one started in its place.
"""

from __future__ import annotations

import os
import signal

import pytest

from hub.cli import record_summary
from hub.config import load_config
from hub.launch import start_local_endpoints
from hub.protocol import MotorCommand, SensorReading
from tests.harness import harness


def _kill_body(h, tmp_path, out, *, restart: bool):
    """SIGKILL the body; with ``restart``, start a new body process in its place."""
    os.kill(h.pid("body"), signal.SIGKILL)
    out["killed"] = True
    if restart:
        overrides = h.overrides + ['culture.launch="external"']  # the body alone
        log_dir = tmp_path / "again"
        log_dir.mkdir()
        h.procs += start_local_endpoints(None, overrides, load_config(None, overrides), log_dir)


def _kill_at(step, h, tmp_path, out, *, restart=True):
    # In the hub's loop thread, which outlives the new process: a child started with
    # PR_SET_PDEATHSIG (hub.launch) is signalled when the thread that started it ends.
    def progress(p):
        if p.step >= step and "killed" not in out:
            _kill_body(h, tmp_path, out, restart=restart)

    return progress


@pytest.mark.parametrize(
    "mode",
    [
        "lockstep",
        pytest.param("realtime", marks=pytest.mark.slow),  # the lockstep case takes the same path
    ],
)
def test_a_body_killed_and_restarted_within_rejoin_s_rejoins_the_run(tmp_path, bus_overrides, mode):
    out: dict = {}
    with harness(
        tmp_path,
        bus_overrides,
        f'loop.mode="{mode}"',
        "experiment.duration_s=4",
        "policy.rejoin_s=20",
        "loop.status_hz=50",
    ) as h:
        result = h.run(progress=_kill_at(50, h, tmp_path, out))
    assert out.get("killed")
    assert result.outcome == "completed" and result.steps == 400
    (rejoin,) = h.record.manifest["rejoins"]
    assert rejoin["role"] == "body" and rejoin["gone_at_step"] >= 50
    assert 0 < rejoin["gap_s"] < 20
    events = [e.key for e in h.record.events if e.key in ("dead", "rejoined")]
    assert events == ["dead", "rejoined"]
    assert record_summary(h.record)["rejoins"] == [rejoin]  # record-info shows it
    sensors, motors = h.received(SensorReading), h.sent(MotorCommand)
    if mode == "lockstep":
        # The loop waited for it: no step is missing, and every reading is the body's
        # answer to that step's command, before and after.
        assert result.counts["missing"] == {}
        assert sorted(sensors) == list(range(400))
    else:
        # Time ran on: the body's steps while it was away are missing, and counted.
        missing = result.counts["missing"]["body"]
        assert missing == 400 - len(sensors) - result.counts["late"].get("body", 0)
        assert missing >= 1 and max(sensors) == 399
    assert all(
        tuple(sensors[k].pose) == (k, motors[k].left_mps, motors[k].right_mps) for k in sensors
    )


def test_a_body_gone_longer_than_rejoin_s_is_dead_by_the_death_policy(tmp_path, bus_overrides):
    out: dict = {}
    with harness(tmp_path, bus_overrides, "experiment.duration_s=30", "policy.rejoin_s=0.5") as h:
        result = h.run(progress=_kill_at(50, h, tmp_path, out, restart=False))
    assert result.outcome == "fault" and "body/0 died" in result.reason
    events = [e.key for e in h.record.events if e.key in ("dead", "rejoin_expired", "rejoined")]
    assert events == ["dead", "rejoin_expired"]
    assert h.record.manifest["rejoins"] == []
