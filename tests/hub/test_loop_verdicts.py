"""The hub's verdict on a reply in realtime depends on when the reply arrived, not on when
the loop looked. (What a reply must contain: tests/hub/test_replies.py.)"""

from __future__ import annotations

import time

from hub.config import load_config
from hub.loop import Hub
from hub.protocol import SensorReading, SpikeBatch, StepWindow


def _hub_at_step(k: int) -> Hub:
    hub = Hub(load_config(None, ['loop.mode="realtime"']))
    hub.state, hub.k = "running", k
    hub.expect = {"body": k, "culture": k}
    hub.last_sent = {"body": k, "culture": k}
    return hub


def _both(k: int, deadline: float) -> tuple[dict, dict]:
    """Both roles owe step k by ``deadline``."""
    return {"body": k, "culture": k}, {"body": deadline, "culture": deadline}


def _replies(hub: Hub, k: int, arrived: dict[str, float]) -> list[tuple]:
    w = StepWindow.of(hub.run_id, k, 0.01)
    raw = {
        "body": SensorReading(
            step=k, run=w.run, t_s=w.t1_s, ranges_m=[0.1], pose=[0.0, 0.0, 0.0], contact=False
        ).encode(),
        "culture": SpikeBatch(**w.stamp, channel=[3], t_ms=[1.0]).encode(),
    }
    return [("rx", role, raw[role], time.time_ns(), t) for role, t in arrived.items()]


def test_replies_in_before_the_deadline_are_on_time_even_if_the_loop_was_held_up():
    hub = _hub_at_step(5)
    deadline = time.monotonic() - 0.002  # the loop's thread comes back 2 ms past the deadline
    for item in _replies(hub, 5, {"body": deadline - 0.004, "culture": deadline - 0.001}):
        hub.inbox.put(item)
    assert hub._collect(*_both(5, deadline)) is False
    assert all(5 in hub.pending[r] for r in ("body", "culture"))
    assert not hub.late and not any(hub.missed.values())


def test_a_reply_in_after_the_deadline_is_late_however_soon_the_loop_sees_it():
    hub = _hub_at_step(5)
    deadline = time.monotonic() - 0.002
    for item in _replies(hub, 5, {"body": deadline - 0.004, "culture": deadline + 0.001}):
        hub.inbox.put(item)
    assert hub._collect(*_both(5, deadline)) is True
    assert 5 in hub.pending["body"] and 5 not in hub.pending["culture"]
    assert hub.late["culture"] == 1 and not hub.late["body"]


def test_a_reply_that_never_comes_is_missing():
    hub = _hub_at_step(2)
    hub.inbox.put(_replies(hub, 2, {"body": time.monotonic()})[0])
    assert hub._collect(*_both(2, time.monotonic() + 0.005)) is True
    assert hub.missed["culture"] == {2} and 2 in hub.pending["body"]
