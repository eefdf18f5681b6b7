"""Faults of the hub's own process, seen from outside: `neuvision run` as a user runs it."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from hub.protocol import MotorCommand
from hub.record import read_run
from tests.conftest import TEST_ENDPOINTS
from tests.harness import wait_for

pytestmark = pytest.mark.bus

FREEZE_S = 2.5  # longer than the 1 s lease: every endpoint's session lapses meanwhile


def _started(runs_dir) -> bool:
    runs = [p for p in runs_dir.iterdir() if p.is_dir()]
    if not runs or not (runs[0] / "record.nvrec").exists():
        return False
    return any(e.key == "start" for e in read_run(runs[0]).events)


def test_a_frozen_hub_names_itself_as_the_cause_and_leaves_the_robot_stopped(
    tmp_path, bus_overrides
):
    sets = [
        a for o in [*TEST_ENDPOINTS, *bus_overrides, "body.params.delay_ms=2"] for a in ("--set", o)
    ]
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hub.cli",
            "run",
            "--quiet",
            "--runs-dir",
            str(tmp_path),
            *sets,
            "--duration-s",
            "600",
        ],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        wait_for(lambda: _started(tmp_path), timeout_s=60)
        proc.send_signal(signal.SIGSTOP)
        time.sleep(FREEZE_S)  # the freeze under test, not a wait for something to happen
        proc.send_signal(signal.SIGCONT)
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 2, stderr
    assert "the hub itself stopped running" in stderr
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    rec = read_run(run_dir)
    assert rec.manifest["outcome"] == "fault"
    assert "the hub itself" in rec.manifest["reason"]
    last = rec.decoded(MotorCommand, "tx")[-1]
    assert last.left_mps == last.right_mps == 0
