"""Compiled work of the stimulation limits (``limits.py``), one call per check.

The rate limit's state is plain arrays: the channels seen so far (``ids``, sorted) with
each one's pulses in the window (``counts``), and the delivered pulses in time order in
a ring buffer (``ring_t`` their times, ``ring_c`` their channels; ``pos`` holds the
ring's head and length). A channel is found by binary search in ``ids``, so a channel
of any uint32 number costs what channel 0 costs.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types

from hub.array_kernels import any_array

OK = 0
AMPLITUDE = 1  # a pulse's absolute amplitude is over the limit
WIDTH = 2  # a pulse's width is over the limit
RATE = 3  # a channel's pulses in the window would be over the limit
UNKNOWN = 4  # a channel not in ``ids``: add it and call again
FULL = 5  # the ring has no room for the pulses: grow it and call again


# A message's arrays: read-only or not, any layout (the kernels read them only); the
# kernels are compiled for these (or loaded from numba's cache) when this module is imported.
_PULSES_U4 = any_array(types.uint32)
_PULSES_F4 = any_array(types.float32)
_STATE_I8 = types.Array(types.int64, 1, "C")
_STATE_F8 = types.Array(types.float64, 1, "C")
_F8 = types.float64


@njit(cache=True, inline="always")
def _slot(ids, channel):
    """Index of ``channel`` in the sorted ``ids``, or -1."""
    lo, hi = 0, ids.size
    while lo < hi:
        mid = (lo + hi) >> 1
        if ids[mid] < channel:
            lo = mid + 1
        else:
            hi = mid
    if lo < ids.size and ids[lo] == channel:
        return lo
    return -1


@njit(
    [
        (
            _PULSES_U4, _PULSES_F4, _PULSES_F4, _F8, _F8, types.boolean, _F8, _F8,
            _STATE_I8, _STATE_I8, _STATE_F8, _STATE_I8, _STATE_I8,
        )
    ],
    cache=True,
)  # fmt: skip
def check(
    channel, amplitude_ua, width_ms, max_amplitude_ua, max_width_ms,
    rate, since_s, allowed, ids, counts, ring_t, ring_c, pos,
):  # fmt: skip
    """The first limit a stimulation's pulses break, as ``(code, value, index)``.

    ``AMPLITUDE`` and ``WIDTH`` give the largest absolute amplitude or width as
    ``value``; ``RATE`` gives the pulse whose channel goes over (its first appearance)
    as ``index`` and that channel's count with the pulses asked for as ``value``;
    ``UNKNOWN`` a pulse on a channel not in ``ids``. With ``rate`` true the pulses at
    or before ``since_s`` leave the window first. Nothing is counted.

    Parameters
    ----------
    channel, amplitude_ua, width_ms : 1-D arrays
        The stimulation's pulses (uint32, float32, float32).
    max_amplitude_ua, max_width_ms : float
        The limits (infinite: not checked).
    rate : bool
        Whether the rate limit is checked.
    since_s : float
        Run time at which the rate window starts (pulses at or before it leave).
    allowed : float
        Pulses a channel may have in the window.
    ids, counts, ring_t, ring_c, pos
        The rate limit's state (module docstring), updated in place.
    """
    n = channel.size
    top = 0.0
    for i in range(n):
        top = max(top, abs(np.float64(amplitude_ua[i])))
    if top > max_amplitude_ua:
        return AMPLITUDE, top, -1
    top = 0.0
    for i in range(n):
        top = max(top, np.float64(width_ms[i]))
    if top > max_width_ms:
        return WIDTH, top, -1
    if not rate:
        return OK, 0.0, -1
    head, length = pos[0], pos[1]
    cap = ring_t.size
    while length and ring_t[head] <= since_s:
        counts[_slot(ids, ring_c[head])] -= 1
        head = (head + 1) % cap
        length -= 1
    pos[0], pos[1] = head, length
    slots = np.empty(n, np.int64)
    for i in range(n):
        s = _slot(ids, np.int64(channel[i]))
        if s < 0:
            return UNKNOWN, 0.0, i
        slots[i] = s
    for i in range(n):  # the asked pulses counted in, to be taken out again below
        counts[slots[i]] += 1
    code, value, index = OK, 0.0, -1
    for i in range(n):  # the first pulse over the limit is its channel's first appearance
        if counts[slots[i]] > allowed:
            code, value, index = RATE, np.float64(counts[slots[i]]), i
            break
    for i in range(n):
        counts[slots[i]] -= 1
    return code, value, index


@njit(
    [(_PULSES_U4, _PULSES_F4, _F8, _STATE_I8, _STATE_I8, _STATE_F8, _STATE_I8, _STATE_I8)],
    cache=True,
)
def accept(channel, onset_ms, t0_s, ids, counts, ring_t, ring_c, pos):
    """Count the pulses of a delivered stimulation: ``OK``, or ``UNKNOWN`` / ``FULL``
    with nothing counted.

    Parameters
    ----------
    channel, onset_ms : 1-D arrays
        The stimulation's pulses (uint32, float32).
    t0_s : float
        Run time of the step's start: a pulse's time is ``t0_s + onset_ms / 1e3``.
    ids, counts, ring_t, ring_c, pos
        The rate limit's state (module docstring), updated in place.
    """
    n = channel.size
    head, length = pos[0], pos[1]
    cap = ring_t.size
    if length + n > cap:
        return FULL
    slots = np.empty(n, np.int64)
    for i in range(n):
        s = _slot(ids, np.int64(channel[i]))
        if s < 0:
            return UNKNOWN
        slots[i] = s
    times = np.empty(n, np.float64)
    for i in range(n):
        times[i] = t0_s + np.float64(onset_ms[i]) / 1e3
    order = np.argsort(times, kind="mergesort")
    for j in range(n):
        i = order[j]
        at = (head + length) % cap
        ring_t[at] = times[i]
        ring_c[at] = channel[i]
        length += 1
        counts[slots[i]] += 1
    pos[1] = length
    return OK
