"""The per-channel pulse rate limit: at most ``max_pulse_hz`` pulses a channel in any
trailing second, counting the pulses delivered and the stimulation asked for."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hub import limits as limits_module
from hub.limits import RATE_WINDOW_S, StimulationLimits
from hub.protocol import Stimulation
from tests.endpoints import EchoCulture
from tests.windows import PERIOD_S, W

CULTURE = dataclasses.replace(
    EchoCulture().describe(), max_amplitude_ua=100.0, max_width_ms=1.0, max_pulse_hz=5.0
)
ALLOWED = int(CULTURE.max_pulse_hz * RATE_WINDOW_S)  # pulses a channel may have in a window
STEPS_PER_WINDOW = round(RATE_WINDOW_S / PERIOD_S)


def stim(k: int, channels, onsets_ms=None, period_s: float = PERIOD_S) -> Stimulation:
    """Pulses on ``channels`` during step ``k``, each 5 ms into it unless told."""
    n = len(channels)
    return Stimulation(
        **W(k, period_s).stamp,
        channel=np.asarray(channels, np.uint32),
        amplitude_ua=np.full(n, 10.0, np.float32),
        width_ms=np.full(n, 0.2, np.float32),
        onset_ms=np.full(n, 5.0, np.float32) if onsets_ms is None else onsets_ms,
    )


def deliver(limits: StimulationLimits, s: Stimulation) -> str | None:
    why = limits.violation(s)
    if why is None:
        limits.accept(s)
    return why


def test_a_channel_takes_its_limit_in_a_window_and_not_one_pulse_more():
    limits = StimulationLimits(CULTURE)
    for k in range(ALLOWED):
        assert deliver(limits, stim(k, [3])) is None
    why = deliver(limits, stim(ALLOWED, [3]))
    assert why == f"channel 3: {ALLOWED + 1} pulses in 1 s exceed max_pulse_hz 5"
    assert deliver(limits, stim(ALLOWED, [4])) is None  # another channel is not counted


def test_a_refused_stimulation_is_not_counted_and_pulses_leave_the_window():
    limits = StimulationLimits(CULTURE)
    for k in range(ALLOWED):
        deliver(limits, stim(k, [3]))
    for k in range(ALLOWED, STEPS_PER_WINDOW):
        assert deliver(limits, stim(k, [3])) is not None
    # the first pulse (5 ms) is out of the window ending with step 100's end (1.01 s)
    assert deliver(limits, stim(STEPS_PER_WINDOW, [3])) is None
    assert deliver(limits, stim(STEPS_PER_WINDOW + 1, [3])) is None
    assert deliver(limits, stim(STEPS_PER_WINDOW + 1, [3])) is not None


def test_pulses_of_one_stimulation_on_one_channel_count_together():
    limits = StimulationLimits(CULTURE)
    assert deliver(limits, stim(0, [7] * (ALLOWED + 1))) is not None
    assert deliver(limits, stim(0, [7] * ALLOWED + [8])) is None
    assert "channel 7: 6 pulses" in deliver(limits, stim(1, [8, 7]))


def test_a_channel_of_any_number_is_counted_like_any_other():
    """A scheme's or an input's channel may be any uint32: counting it takes no more than
    counting channel 0 (nothing sized by the channel's number)."""
    limits = StimulationLimits(CULTURE)
    top = 2**32 - 1
    for k in range(ALLOWED):
        assert deliver(limits, stim(k, [top, 0])) is None
    assert deliver(limits, stim(ALLOWED, [top])).startswith(f"channel {top}: 6 pulses")


def test_a_pulse_counts_from_its_onset_not_its_steps_start():
    early, late = StimulationLimits(CULTURE), StimulationLimits(CULTURE)
    deliver(early, stim(0, [1], onsets_ms=[0.0]))
    deliver(late, stim(0, [1], onsets_ms=[9.0]))
    for k in range(1, ALLOWED):
        deliver(early, stim(k, [1]))
        deliver(late, stim(k, [1]))
    # the window ending with step 99's end (1.00 s) starts after 0 s, before 9 ms
    last = STEPS_PER_WINDOW - 1
    assert deliver(early, stim(last, [1])) is None
    assert deliver(late, stim(last, [1])) is not None


class Reference:
    """The rule written plainly: every delivered pulse's time, counted per channel."""

    def __init__(self, allowed: float):
        self.allowed = allowed
        self.times: dict[int, list[float]] = {}

    def violation(self, s: Stimulation) -> int | None:
        since_s = s.t1_s - RATE_WINDOW_S
        for channel in dict.fromkeys(s.channel.tolist()):
            asked = int(np.sum(s.channel == channel))
            kept = sum(t > since_s for t in self.times.get(channel, []))
            if kept + asked > self.allowed:
                return channel
        return None

    def accept(self, s: Stimulation) -> None:
        for channel, onset_ms in zip(s.channel.tolist(), s.onset_ms.tolist(), strict=True):
            self.times.setdefault(channel, []).append(s.t0_s + onset_ms / 1e3)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("period_s", [PERIOD_S, 0.007])
def test_the_limit_refuses_exactly_what_the_rule_refuses(seed, period_s):
    """Random stimulations, some near the limit, their pulses in any order: each refused by
    the limits iff by the rule written plainly, for the same channel. At a 7 ms period the
    window's start falls inside a step, between the pulses of one stimulation."""
    refuses_what_the_rule_refuses(np.random.default_rng(seed), period_s)


def test_the_delivered_pulses_outgrow_their_first_room_and_count_on(monkeypatch):
    """The delivered pulses are kept in a buffer that grows as needed, oldest first."""
    monkeypatch.setattr(limits_module, "_RING_START", 2)
    refuses_what_the_rule_refuses(np.random.default_rng(11), 0.007)


def test_a_stimulation_made_of_strided_arrays_is_checked_like_any_other():
    """A message may hold views (writable, strided) of a scheme's arrays."""
    limits = StimulationLimits(CULTURE)
    every_other = np.full(2 * (ALLOWED + 1), 3, np.uint32)[::2]
    s = Stimulation(
        **W(0).stamp,
        channel=every_other,
        amplitude_ua=np.full(2 * (ALLOWED + 1), 10.0, np.float32)[::2],
        width_ms=np.full(ALLOWED + 1, 0.2, np.float32),
        onset_ms=np.full(ALLOWED + 1, 5.0, np.float32),
    )
    assert deliver(limits, s) == f"channel 3: {ALLOWED + 1} pulses in 1 s exceed max_pulse_hz 5"


def refuses_what_the_rule_refuses(rng: np.random.Generator, period_s: float) -> None:
    culture = dataclasses.replace(CULTURE, max_pulse_hz=float(rng.choice([3, 8, 25])))
    limits, reference = StimulationLimits(culture), Reference(culture.max_pulse_hz * 1.0)
    refused = 0
    for k in range(600):
        n = int(rng.integers(0, 6))
        channels = rng.integers(0, 4, n)
        onsets = (rng.random(n) * period_s * 1e3 * 0.99).astype(np.float32)
        s = stim(k, channels, onsets, period_s)
        expected = reference.violation(s)
        why = limits.violation(s)
        if expected is None:
            assert why is None, f"step {k}: {why}"
            limits.accept(s)
            reference.accept(s)
        else:
            refused += 1
            assert why is not None and why.startswith(f"channel {expected}:"), f"step {k}"
    assert refused > 20  # the streams do reach the limit
