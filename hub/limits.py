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

import math

import numpy as np

from hub import limits_kernels as kernels
from hub.protocol import Description, MotorCommand, Stimulation

# Pulses are counted over this trailing window for the per-channel rate limit.
RATE_WINDOW_S = 1.0
# Pulses the ring of delivered pulses holds at first (it grows as needed).
_RING_START = 4096
_f32 = np.float32


# A pulse's amplitude and width travel as float32 (Stimulation's schema): a value asked
# for exactly at a limit may arrive just above it (a 0.8 ms width as 0.80000001 ms). So
# they are compared with the limit at the wire's precision: the limit itself passes, the
# next float32 value above it does not.
def over(value: float, limit: float) -> bool:
    """``value`` is over ``limit`` at float32 precision (the wire's, for pulses).

    Parameters
    ----------
    value, limit : float
        Both rounded to float32 before they are compared.
    """
    return _f32(value) > _f32(limit)


def _as_f32(limit: float | None) -> float | None:
    """``limit`` rounded to float32, as a Python float: a float32 value is ``over`` it
    exactly when greater (both exact in float64)."""
    return None if limit is None else float(_f32(limit))


def under(value: float, limit: float) -> bool:
    """``value`` is under ``limit`` at float32 precision (the wire's, for pulses).

    Parameters
    ----------
    value, limit : float
        Both rounded to float32 before they are compared.
    """
    return _f32(value) < _f32(limit)


def motor_violation(motor: MotorCommand, body: Description) -> str | None:
    """Why ``motor`` exceeds the body's ``max_wheel_mps``, or None if it does not.

    Parameters
    ----------
    motor : MotorCommand
        The wheel speeds asked for (either sign).
    body : Description
        The body's description; ``max_wheel_mps`` None is not checked.
    """
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
    The work is compiled (``limits_kernels.py``): the hub and a culture's endpoint each
    check every step's stimulation.

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
        self._amplitude_f32 = _unbounded(_as_f32(culture.max_amplitude_ua))
        self._width_f32 = _unbounded(_as_f32(culture.max_width_ms))
        self._rate = culture.max_pulse_hz is not None
        self._allowed = (culture.max_pulse_hz or 0.0) * RATE_WINDOW_S
        # The channels seen (sorted) with their pulses in the window, and the delivered
        # pulses' times and channels, oldest first, in a ring (head and length in _pos).
        self._ids = np.zeros(0, np.int64)
        self._counts = np.zeros(0, np.int64)
        self._ring_t = np.zeros(_RING_START, np.float64)
        self._ring_c = np.zeros(_RING_START, np.int64)
        self._pos = np.zeros(2, np.int64)
        limits = (culture.max_amplitude_ua, culture.max_width_ms, culture.max_pulse_hz)
        self._checked = any(limit is not None for limit in limits)  # else nothing to check

    def violation(self, stim: Stimulation) -> str | None:
        """Why ``stim`` may not be delivered, or None. Call :meth:`accept` if delivered."""
        if not (stim.n_pulses and self._checked):
            return None
        while True:
            code, value, index = kernels.check(
                stim.channel, stim.amplitude_ua, stim.width_ms, self._amplitude_f32,
                self._width_f32, self._rate, stim.t1_s - RATE_WINDOW_S, self._allowed,
                self._ids, self._counts, self._ring_t, self._ring_c, self._pos,
            )  # fmt: skip
            if code == kernels.OK:
                return None
            if code != kernels.UNKNOWN:
                break
            self._add_channels(stim.channel)
        if code == kernels.AMPLITUDE:
            return f"amplitude {value:g} uA exceeds max_amplitude_ua {self.max_amplitude_ua:g}"
        if code == kernels.WIDTH:
            return f"width {value:g} ms exceeds max_width_ms {self.max_width_ms:g}"
        return (
            f"channel {int(stim.channel[index])}: {int(value)} pulses in {RATE_WINDOW_S:g} s "
            f"exceed max_pulse_hz {self.max_pulse_hz:g}"
        )

    def accept(self, stim: Stimulation) -> None:
        """Count ``stim``'s pulses towards the rate limit (it is being delivered)."""
        if not self._rate or not stim.n_pulses:
            return
        while True:
            code = kernels.accept(
                stim.channel, stim.onset_ms, stim.t0_s,
                self._ids, self._counts, self._ring_t, self._ring_c, self._pos,
            )  # fmt: skip
            if code == kernels.OK:
                return
            if code == kernels.UNKNOWN:
                self._add_channels(stim.channel)
            else:
                self._grow(stim.n_pulses)

    def _add_channels(self, channel: np.ndarray) -> None:
        """Make room in the counts for the channels of ``channel`` not seen before."""
        ids = np.union1d(self._ids, channel.astype(np.int64))
        counts = np.zeros(ids.size, np.int64)
        counts[np.searchsorted(ids, self._ids)] = self._counts
        self._ids, self._counts = ids, counts

    def _grow(self, more: int) -> None:
        """A ring with room for ``more`` pulses besides those it holds, oldest first."""
        head, length = int(self._pos[0]), int(self._pos[1])
        cap = max(2 * self._ring_t.size, length + more)
        kept = (head + np.arange(length)) % self._ring_t.size
        ring_t, ring_c = np.zeros(cap, np.float64), np.zeros(cap, np.int64)
        ring_t[:length], ring_c[:length] = self._ring_t[kept], self._ring_c[kept]
        self._ring_t, self._ring_c = ring_t, ring_c
        self._pos[0] = 0


def _unbounded(limit: float | None) -> float:
    """A limit for the kernels: None (not checked) is infinite."""
    return math.inf if limit is None else limit
