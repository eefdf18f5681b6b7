"""What a reply must contain to be taken: its run, its step's window, and what its endpoint
described (a body's sensors and range, a culture's channels)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hub.protocol import Description, ProtocolError, SensorReading, SpikeBatch, StepWindow
from hub.replies import ReplyChecker
from tests.windows import PERIOD_S, RUN, W

BODY = Description(
    role="body",
    id="0",
    kind="test",
    sensor_angles_rad=[0.0, 1.0],
    max_range_m=0.5,
    wheel_base_m=0.1,
    radius_m=0.05,
    max_wheel_mps=0.2,
)
CHANNELS = np.arange(10, 210, 2)  # 100 channels, even ids only
CULTURE = Description(
    role="culture", id="0", kind="test", channel=CHANNELS, x_um=CHANNELS * 1.0, y_um=CHANNELS * 1.0
)


def checker() -> ReplyChecker:
    c = ReplyChecker(RUN, PERIOD_S)
    c.take_description(BODY)
    c.take_description(CULTURE)
    return c


STEP_5 = W(5)


def spikes(channel, window: StepWindow = STEP_5) -> bytes:
    t_ms = np.linspace(0, 9, len(channel))
    return SpikeBatch(**window.stamp, channel=channel, t_ms=t_ms).encode()


def sensors(ranges, t_s: float = STEP_5.t1_s, run: str = RUN) -> bytes:
    return SensorReading(
        step=5, run=run, t_s=t_s, ranges_m=ranges, pose=[0.0, 0.0, 0.0], contact=False
    ).encode()


def kind_of(role: str, raw: bytes) -> str:
    with pytest.raises(ProtocolError) as err:
        checker().check(role, raw)
    return err.value.kind


@pytest.mark.parametrize("n_spikes", [3, 80])  # checked in plain Python / compiled
def test_spikes_on_channels_the_culture_does_not_have_are_refused(n_spikes):
    known = list(range(10, 10 + 2 * n_spikes, 2))
    assert checker().check("culture", spikes(known)).channel.tolist() == known
    for bad in (known[:-1] + [11], known[:-1] + [9], known[:-1] + [10_000]):
        assert kind_of("culture", spikes(bad)) == "range"


def test_channels_of_any_number_are_checked_without_a_table_that_large():
    """A culture may number its channels up to 2**32 - 1 (a table by number would take
    4 GB): those are looked up in a set."""
    numbers = np.array([7, 2**31, 2**32 - 1], np.uint32)
    c = ReplyChecker(RUN, PERIOD_S)
    c.take_description(
        dataclasses.replace(CULTURE, channel=numbers, x_um=[0.0] * 3, y_um=[0.0] * 3)
    )
    many = np.repeat(numbers, 30)  # past SMALL_ARRAY
    assert np.array_equal(c.check("culture", spikes(many)).channel, many)
    with pytest.raises(ProtocolError, match="channels the culture does not have"):
        c.check("culture", spikes(np.r_[many[:-1], 8].astype(np.uint32)))


def test_sensor_readings_unlike_the_body_described_are_refused():
    assert checker().check("body", sensors([0.1, 0.5])).step == 5
    assert kind_of("body", sensors([0.1])) == "array"
    assert kind_of("body", sensors([0.1, 0.6])) == "range"


def test_a_reply_of_another_run_is_foreign():
    assert kind_of("body", sensors([0.1, 0.2], run="f" * 32)) == "foreign"
    other = StepWindow.of("f" * 32, 5, PERIOD_S)
    assert kind_of("culture", spikes([10], other)) == "foreign"


def test_a_reply_for_another_window_is_refused():
    shifted = StepWindow(RUN, 5, W(4).t0_s, W(4).t1_s)  # step 5 claiming step 4's window
    assert kind_of("culture", spikes([10], shifted)) == "window"
    assert kind_of("body", sensors([0.1, 0.2], t_s=W(6).t1_s)) == "window"  # taken later
    earlier = checker().check(
        "body", sensors([0.1, 0.2], t_s=W(3).t1_s)
    )  # a device's older reading
    assert earlier.t_s == W(3).t1_s


def test_a_malformed_reply_is_refused_with_the_schemas_kind():
    assert kind_of("culture", b"\xc1") == "not_msgpack"
