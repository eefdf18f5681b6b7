"""The hub's verdict on a reply: in realtime it depends on when the reply arrived, not on
when the loop looked; and a reply unlike what its endpoint described is dropped."""

from __future__ import annotations

import time

import numpy as np
import pytest

from hub.config import load_config
from hub.loop import Hub
from hub.protocol import Description, SensorReading, SpikeBatch, StepWindow


def _hub_at_step(k: int) -> Hub:
    hub = Hub(load_config(None, ['loop.mode="realtime"']))
    hub.state, hub.k = "running", k
    hub.expect = {"body": k, "culture": k}
    hub.last_sent = {"body": k, "culture": k}
    return hub


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
    assert hub._collect(5, deadline) is False
    assert all(5 in hub.pending[r] for r in ("body", "culture"))
    assert not hub.late and not any(hub.missed.values())


def test_a_reply_in_after_the_deadline_is_late_however_soon_the_loop_sees_it():
    hub = _hub_at_step(5)
    deadline = time.monotonic() - 0.002
    for item in _replies(hub, 5, {"body": deadline - 0.004, "culture": deadline + 0.001}):
        hub.inbox.put(item)
    assert hub._collect(5, deadline) is True
    assert 5 in hub.pending["body"] and 5 not in hub.pending["culture"]
    assert hub.late["culture"] == 1 and not hub.late["body"]


def test_a_reply_that_never_comes_is_missing():
    hub = _hub_at_step(2)
    hub.inbox.put(_replies(hub, 2, {"body": time.monotonic()})[0])
    assert hub._collect(2, time.monotonic() + 0.005) is True
    assert hub.missed["culture"] == {2} and 2 in hub.pending["body"]


def _described_hub() -> Hub:
    hub = _hub_at_step(5)
    hub._take_description(
        Description(
            role="body",
            id="0",
            kind="test",
            sensor_angles_rad=[0.0, 1.0],
            max_range_m=0.5,
            wheel_base_m=0.1,
            radius_m=0.05,
            max_wheel_mps=0.2,
        )
    )
    channels = np.arange(10, 210, 2)  # 100 channels, even ids only
    hub._take_description(
        Description(
            role="culture",
            id="0",
            kind="test",
            channel=channels,
            x_um=channels * 1.0,
            y_um=channels * 1.0,
        )
    )
    return hub


def _spikes(hub: Hub, channel) -> bytes:
    n = len(channel)
    w = StepWindow.of(hub.run_id, 5, 0.01)
    return SpikeBatch(**w.stamp, channel=channel, t_ms=np.linspace(0, 9, n)).encode()


def _sensors(hub: Hub, ranges) -> bytes:
    return SensorReading(
        step=5, run=hub.run_id, t_s=0.05, ranges_m=ranges, pose=[0.0, 0.0, 0.0], contact=False
    ).encode()


@pytest.mark.parametrize("n_spikes", [3, 80])  # checked in plain Python / with numpy
def test_spikes_on_channels_the_culture_does_not_have_are_dropped(n_spikes):
    hub = _described_hub()
    known = list(range(10, 10 + 2 * n_spikes, 2))
    assert hub._classify_reply("culture", _spikes(hub, known), time.monotonic()) == "rx"
    hub.pending["culture"].clear()
    for bad in (known[:-1] + [11], known[:-1] + [9], known[:-1] + [10_000]):
        assert hub._classify_reply("culture", _spikes(hub, bad), time.monotonic()) == "drop"
    assert hub.dropped["culture"]["range"] == 3


def test_sensor_readings_unlike_the_body_described_are_dropped():
    hub = _described_hub()
    assert hub._classify_reply("body", _sensors(hub, [0.1, 0.5]), time.monotonic()) == "rx"
    hub.pending["body"].clear()
    assert hub._classify_reply("body", _sensors(hub, [0.1]), time.monotonic()) == "drop"
    assert hub._classify_reply("body", _sensors(hub, [0.1, 0.6]), time.monotonic()) == "drop"
    assert hub.dropped["body"] == {"array": 1, "range": 1}


def test_a_reply_of_another_run_or_window_is_dropped():
    hub = _described_hub()
    other = StepWindow.of("f" * 32, 5, 0.01)
    stranger = SpikeBatch(**other.stamp, channel=[10], t_ms=[1.0]).encode()
    assert hub._classify_reply("culture", stranger, time.monotonic()) == "drop"
    shifted = StepWindow(hub.run_id, 5, 0.04, 0.05)  # step 5 claiming step 4's window
    assert (
        hub._classify_reply(
            "culture", SpikeBatch(**shifted.stamp, channel=[10], t_ms=[1.0]).encode(), 0.0
        )
        == "drop"
    )
    future = SensorReading(
        step=5, run=hub.run_id, t_s=0.07, ranges_m=[0.1, 0.2], pose=[0.0, 0.0, 0.0], contact=False
    ).encode()  # a reading taken after its window ended
    assert hub._classify_reply("body", future, time.monotonic()) == "drop"
    assert hub.dropped["culture"] == {"foreign": 1, "window": 1}
    assert hub.dropped["body"] == {"window": 1}
