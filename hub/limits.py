"""Limits on what may reach a device: stimulation and wheel speeds (contract v2).

A culture describes the stimulation it takes (``Description.max_amplitude_ua``,
``max_width_ms``, ``max_pulse_hz`` per channel), a body its top wheel speed
(``max_wheel_mps``). Both sides check every message against them — the culture or body
endpoint on what it receives, the hub on what its coding and decoding schemes make —
with the functions here, so there is one definition of "over the limit". A message over
a limit is refused whole and counted (``limit``), never clipped: a scheme or a stranger
that asks for 1e6 µA gets nothing delivered rather than something else.
"""

from __future__ import annotations

from bisect import bisect_right
from collections import Counter, deque

import numpy as np

from hub.protocol import SMALL_ARRAY, Description, MotorCommand, Stimulation

# Pulses are counted over this trailing window for the per-channel rate limit.
RATE_WINDOW_S = 1.0
_f32 = np.float32


# A pulse's amplitude and width travel as float32 (Stimulation's schema): a value asked
# for exactly at a limit may arrive just above it (a 0.8 ms width as 0.80000001 ms). So
# they are compared with the limit at the wire's precision: the limit itself passes, the
# next float32 value above it does not.
def over(value: float, limit: float) -> bool:
    """``value`` is over ``limit`` at float32 precision (the wire's, for pulses)."""
    return _f32(value) > _f32(limit)


def _as_f32(limit: float | None) -> float | None:
    """``limit`` rounded to float32, as a Python float: a float32 value is ``over`` it
    exactly when greater (both exact in float64)."""
    return None if limit is None else float(_f32(limit))


def under(value: float, limit: float) -> bool:
    """``value`` is under ``limit`` at float32 precision (the wire's, for pulses)."""
    return _f32(value) < _f32(limit)


def motor_violation(motor: MotorCommand, body: Description) -> str | None:
    """Why ``motor`` exceeds the body's ``max_wheel_mps``, or None if it does not."""
    limit = body.max_wheel_mps
    if limit is None:
        return None
    fastest = max(abs(motor.left_mps), abs(motor.right_mps))
    if fastest > limit * (1 + 1e-9):
        return f"wheel speed {fastest:g} m/s exceeds max_wheel_mps {limit:g}"
    return None


class StimulationLimits:
    """Checks each step's :class:`Stimulation` against a culture's described limits.

    Amplitude (absolute value) and width per pulse; pulses per channel over the last
    :data:`RATE_WINDOW_S` (``max_pulse_hz`` per channel). Onsets inside the step are a
    rule of the message itself (``Stimulation`` refuses an onset outside its window).

    Parameters
    ----------
    culture : Description
        The culture's description; its ``max_*`` fields that are None are not checked.
    """

    def __init__(self, culture: Description):
        self.max_amplitude_ua = culture.max_amplitude_ua
        self.max_width_ms = culture.max_width_ms
        self.max_pulse_hz = culture.max_pulse_hz
        # The limits as float32 (see ``over``): a pulse's values are float32 already.
        self._amplitude_f32 = _as_f32(culture.max_amplitude_ua)
        self._width_f32 = _as_f32(culture.max_width_ms)
        # The rate limit counts, per channel, the delivered pulses that entered the window
        # and those that left it (a channel's pulses in the window are the difference; each
        # count is one C-level Counter.update a step, not a lookup a pulse), and keeps the
        # delivered stimulations, oldest first, to take their pulses out as the window
        # passes them.
        self._entered: Counter[int] = Counter()
        self._left: Counter[int] = Counter()
        self._top = 0  # at least the largest count: below the limit, no channel is checked
        self._delivered: deque[_Delivered] = deque()

    def violation(self, stim: Stimulation) -> str | None:
        """Why ``stim`` may not be delivered, or None. Call :meth:`accept` if delivered."""
        if not stim.n_pulses:
            return None
        small = stim.n_pulses <= SMALL_ARRAY  # plain Python beats numpy calls here
        if self._amplitude_f32 is not None:
            amplitude = stim.amplitude_ua
            if small:
                values = amplitude.tolist()
                top = max(max(values), -min(values))  # the largest absolute value
            else:
                top = float(np.abs(amplitude).max())
            if top > self._amplitude_f32:
                return f"amplitude {top:g} uA exceeds max_amplitude_ua {self.max_amplitude_ua:g}"
        if self._width_f32 is not None:
            top = max(stim.width_ms.tolist()) if small else float(stim.width_ms.max())
            if top > self._width_f32:
                return f"width {top:g} ms exceeds max_width_ms {self.max_width_ms:g}"
        if self.max_pulse_hz is not None:
            return self._rate_violation(stim.channel.tolist(), stim.t1_s - RATE_WINDOW_S)
        return None

    def _rate_violation(self, channels: list[int], since_s: float) -> str | None:
        self._forget(since_s)
        allowed = self.max_pulse_hz * RATE_WINDOW_S
        n = len(channels)  # no channel can be asked for more than all the pulses
        if self._top + n <= allowed:
            return None
        entered, left = self._entered, self._left.get
        self._top = max((k - left(c, 0) for c, k in entered.items()), default=0)
        if self._top + n <= allowed:
            return None
        asked = dict.fromkeys(channels, 1) if len(set(channels)) == n else Counter(channels)
        for channel, k in asked.items():  # in order of first appearance
            k += entered.get(channel, 0) - left(channel, 0)
            if k > allowed:
                return (
                    f"channel {channel}: {k} pulses in {RATE_WINDOW_S:g} s exceed "
                    f"max_pulse_hz {self.max_pulse_hz:g}"
                )
        return None

    def accept(self, stim: Stimulation) -> None:
        """Count ``stim``'s pulses towards the rate limit (it is being delivered)."""
        if self.max_pulse_hz is None or not stim.n_pulses:
            return
        channels = stim.channel.tolist()
        self._entered.update(channels)
        # the largest count grows by at most the most pulses on one channel here
        distinct = len(set(channels)) == len(channels)
        self._top += 1 if distinct else max(Counter(channels).values())
        self._delivered.append(_Delivered(stim.t0_s, stim.onset_ms.tolist(), channels))

    def _forget(self, since_s: float) -> None:
        """Take the pulses at or before ``since_s`` (out of the window) out of the counts."""
        delivered, left = self._delivered, self._left
        while delivered:
            oldest = delivered[0]
            if oldest.last_s <= since_s:
                left.update(oldest.channels)
                delivered.popleft()
            elif oldest.first_s > since_s:
                return
            else:
                left.update(oldest.forget(since_s))


class _Delivered:
    """The pulses of one delivered stimulation still in the rate limit's window.

    A pulse's time is ``t0_s + onset_ms / 1e3``; that is monotonic in the onset, so the
    first and last times come from the smallest and largest onsets, and each pulse's time
    is computed only for the stimulation the window's start falls inside.
    """

    __slots__ = ("t0_s", "onsets_ms", "channels", "first_s", "last_s")

    def __init__(self, t0_s: float, onsets_ms: list[float], channels: list[int]):
        if onsets_ms != sorted(onsets_ms):
            pulses = sorted(zip(onsets_ms, channels, strict=True))
            onsets_ms, channels = [p[0] for p in pulses], [p[1] for p in pulses]
        self.t0_s, self.onsets_ms, self.channels = t0_s, onsets_ms, channels
        self.first_s = t0_s + onsets_ms[0] / 1e3
        self.last_s = t0_s + onsets_ms[-1] / 1e3

    def forget(self, since_s: float) -> list[int]:
        """Drop the pulses at or before ``since_s`` (some, not all); their channels."""
        t0_s = self.t0_s
        times = [t0_s + onset_ms / 1e3 for onset_ms in self.onsets_ms]
        end = bisect_right(times, since_s)
        gone = self.channels[:end]
        self.onsets_ms, self.channels = self.onsets_ms[end:], self.channels[end:]
        self.first_s = times[end]
        return gone
