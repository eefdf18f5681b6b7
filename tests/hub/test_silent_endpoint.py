"""An endpoint that stays on the bus but answers nothing is taken for dead after
``policy.silent_s`` (hub/presence.py), however its silence came about.

Real processes: a second body takes the first one's name on the bus, then the first one is
killed. Zenoh keeps one liveliness token of a name while any process holds it, so the
hub never sees the first one's token go: only its silence tells.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading

from hub import wire
from hub.bus import open_session
from hub.protocol import HubStatus
from tests.harness import harness, subscribed, wait_for


def _status(sample) -> HubStatus:
    return HubStatus.decode(bytes(sample.payload))


def test_a_body_whose_name_another_process_holds_is_taken_for_dead_once_silent(
    tmp_path, bus_overrides
):
    overrides = [
        'loop.mode="realtime"',  # time runs on: each step's body reply missing is stood in
        "experiment.duration_s=30",
        "policy.silent_s=1",
        "loop.status_hz=50",
    ]
    statuses: list[HubStatus] = []
    done = threading.Event()
    duplicate: list[subprocess.Popen] = []

    with harness(tmp_path, bus_overrides, *overrides) as h:
        keys = h.cfg.bus.keys

        def take_its_name_then_kill_it():
            wait_for(lambda: any(s.step > 50 for s in statuses), timeout_s=60)
            sets = [arg for item in h.overrides for arg in ("--set", item)]
            duplicate.append(
                subprocess.Popen(
                    [sys.executable, "-m", "hub.cli", "endpoint", "body", *sets],
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                )
            )
            session = open_session(h.cfg.bus, listener=False)
            try:  # both answer as body/0 once the second is up
                wait_for(
                    lambda: len(wire.get(session, keys.describe("body", "0"), timeout_s=1)) == 2,
                    timeout_s=60,
                )
            finally:
                session.close()
            os.kill(h.pid("body"), signal.SIGKILL)
            done.set()

        actor = threading.Thread(target=take_its_name_then_kill_it, daemon=True)
        actor.start()
        try:
            with subscribed(h.cfg.bus, keys.hub_status, lambda s: statuses.append(_status(s))):
                result = h.run()
        finally:
            actor.join(60)
            for proc in duplicate:
                proc.kill()
                proc.wait()
    assert done.is_set()
    assert result.outcome == "fault" and result.steps < 3000
    assert result.reason.startswith("body/0 died at step")
    assert "answered none of its inputs for 1 s though its token is on the bus" in result.reason
    assert [e.payload for e in h.record.events if e.key == "silent"] == [
        {"role": "body", "id": "0", "silent_s": 1.0}
    ]
    assert not [e for e in h.record.events if e.key == "dead"]  # its token never went
