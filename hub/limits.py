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

from collections import Counter, defaultdict, deque

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
        self._recent: dict[int, deque] = defaultdict(deque)  # channel → pulse times (s)

    def violation(self, stim: Stimulation) -> str | None:
        """Why ``stim`` may not be delivered, or None. Call :meth:`accept` if delivered."""
        if not stim.n_pulses:
            return None
        small = stim.n_pulses <= SMALL_ARRAY  # plain Python beats numpy calls here
        if self._amplitude_f32 is not None:
            amplitude = stim.amplitude_ua
            top = max(map(abs, amplitude.tolist())) if small else float(np.abs(amplitude).max())
            if top > self._amplitude_f32:
                return f"amplitude {top:g} uA exceeds max_amplitude_ua {self.max_amplitude_ua:g}"
        if self._width_f32 is not None:
            top = max(stim.width_ms.tolist()) if small else float(stim.width_ms.max())
            if top > self._width_f32:
                return f"width {top:g} ms exceeds max_width_ms {self.max_width_ms:g}"
        if self.max_pulse_hz is not None:
            allowed = self.max_pulse_hz * RATE_WINDOW_S
            since = stim.t1_s - RATE_WINDOW_S
            channels = stim.channel.tolist()
            if len(set(channels)) == len(channels):  # each channel once: the usual case
                counts = zip(channels, [1] * len(channels), strict=True)
            else:
                counts = Counter(channels).items()
            for channel, n in counts:
                recent = self._recent.get(channel)
                if recent:  # times come in order: what left the window never comes back
                    while recent and recent[0] <= since:
                        recent.popleft()
                    n += len(recent)
                if n > allowed:
                    return (
                        f"channel {channel}: {n} pulses in {RATE_WINDOW_S:g} s exceed "
                        f"max_pulse_hz {self.max_pulse_hz:g}"
                    )
        return None

    def accept(self, stim: Stimulation) -> None:
        """Count ``stim``'s pulses towards the rate limit (it is being delivered)."""
        if self.max_pulse_hz is None or not stim.n_pulses:
            return
        t0_s = stim.t0_s
        recent = self._recent
        for channel, onset_ms in zip(stim.channel.tolist(), stim.onset_ms.tolist(), strict=True):
            recent[channel].append(t0_s + onset_ms / 1e3)
