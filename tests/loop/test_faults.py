"""Faults of the hub's own process, seen from outside: `neuvision run` as a user runs it."""

from __future__ import annotations

import os
import secrets
import signal
import subprocess
import sys
import threading
import time

import msgpack
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hub.bus import free_tcp_port, open_session
from hub.protocol import MotorCommand
from hub.record import RECORD_FILE, read_run
from tests.conftest import TEST_ENDPOINTS
from tests.harness import harness, wait_for

pytestmark = pytest.mark.bus

FREEZE_S = 2.5  # longer than the 1 s lease: every endpoint's session lapses meanwhile


def _resume(pid: int) -> None:
    """SIGCONT, if the process is still there (it may have ended with its run)."""
    try:
        os.kill(pid, signal.SIGCONT)
    except ProcessLookupError:
        pass


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


ACTIONS = st.lists(
    st.tuples(
        st.integers(min_value=5, max_value=80),  # at step
        st.sampled_from(["garbage", "freeze_body"]),
        st.floats(min_value=0.05, max_value=1.6),  # freeze length (s)
        st.sampled_from(["motor", "stim", "sensors", "spikes"]),
    ),
    max_size=4,
)


@settings(max_examples=4, derandomize=True)
@given(actions=ACTIONS, late_every=st.sampled_from([0, 7]))
def test_whatever_happens_the_hub_ends_cleanly_with_a_whole_record_and_the_robot_stopped(
    tmp_path_factory, actions, late_every
):
    tmp_path = tmp_path_factory.mktemp("run")
    bus = [
        f'bus.session="test-{secrets.token_hex(4)}"',
        f'bus.listen=["tcp/127.0.0.1:{free_tcp_port()}"]',
    ]
    todo = sorted(actions)
    with harness(
        tmp_path,
        bus,
        'loop.mode="realtime"',
        "loop.period_ms=10",
        "experiment.duration_s=1.0",
        f"body.params.late_every={late_every}",
    ) as h:
        keys = h.cfg.bus.keys
        stranger = []  # a session of its own, opened once the hub's router is up
        frozen = []

        def act(progress):
            while todo and progress.step >= todo[0][0]:
                _, what, freeze_s, key = todo.pop(0)
                if what == "garbage":
                    if not stranger:
                        stranger.append(open_session(h.cfg.bus, listener=False))
                    target = getattr(keys, key)("0")
                    for raw in (b"\xc1", os.urandom(32), b""):
                        stranger[0].put(target, raw)
                else:
                    pid = h.pid("body")
                    os.kill(pid, signal.SIGSTOP)
                    frozen.append(pid)
                    threading.Timer(freeze_s, _resume, (pid,)).start()

        try:
            result = h.run(progress=act)
        finally:
            for pid in frozen:
                _resume(pid)
            for session in stranger:
                session.close()
    # The hub never crashed: the run completed or ended as a fault it named.
    assert result.outcome in ("completed", "fault"), result.reason
    if result.outcome == "fault":
        assert "body/0" in result.reason
    # Every frame written is read back (the file's header is not a frame).
    assert len(h.record.frames) + 1 == _objects_in(h.run_dir / RECORD_FILE)
    # Its last word to the body is a stop.
    last = h.record.decoded(MotorCommand, "tx")[-1]
    assert last.left_mps == last.right_mps == 0


def _objects_in(path) -> int:
    """The msgpack objects a file holds, read without the record's reader."""
    with open(path, "rb") as fh:
        return sum(1 for _ in msgpack.Unpacker(fh, raw=False, strict_map_key=False))
