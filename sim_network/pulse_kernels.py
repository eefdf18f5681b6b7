"""Compiled work on stimulation pulses: their values checked, scheduled in neuron space.

A step of a closed loop brings a few dozen pulses; in numpy each of these would be a dozen
small calls. The kernels take any 1-D arrays of the right dtypes (read-only or not, any
layout): they are compiled for those (or loaded from numba's cache) when this module is
imported.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types


def _any(dtype):
    """A 1-D array of ``dtype`` as numba types it, whatever its flags."""
    return types.Array(dtype, 1, "A", readonly=True, aligned=False)


_U4, _F4, _I8, _F8 = (_any(t) for t in (types.uint32, types.float32, types.int64, types.float64))


@njit([(_F4, _F4, _F4)], cache=True)
def values_ok(amplitude_ua, width_ms, onset_ms):
    """True if every amplitude is finite and every width and onset finite and >= 0.

    Parameters
    ----------
    amplitude_ua, width_ms, onset_ms : float32[n]
        The pulses' amplitudes (µA), widths and onsets (ms); same length.
    """
    for i in range(amplitude_ua.size):
        if not np.isfinite(amplitude_ua[i]):
            return False
        w, o = width_ms[i], onset_ms[i]
        if not (w >= 0.0 and o >= 0.0 and np.isfinite(w) and np.isfinite(o)):
            return False
    return True


@njit(cache=True)
def _none():
    """No pulses."""
    return (
        np.empty(0, np.int64), np.empty(0, np.float64), np.empty(0, np.int64),
        np.empty(0, np.int64),
    )  # fmt: skip


@njit(
    [
        (
            _I8, _F8, _I8, _I8, _U4, _F4, _F4, _F4, types.int64, types.float64, types.float64,
            types.int64, _I8, _I8, types.boolean,
        )
    ],
    cache=True,
)  # fmt: skip
def scheduled(
    p_neuron, p_current, p_start, p_end, channel, amplitude_ua, width_ms, onset_ms,
    step, dt, current_per_ua, n_channels, stim_indptr, stim_neuron, mea,
):  # fmt: skip
    """The pending pulses with these added, stably sorted by start step.

    A pulse with onset ``o`` and width ``w`` (ms) is on over steps ``[step + rint(o / dt),
    that + rint(w / dt))`` with current ``amplitude * current_per_ua``; with ``mea`` its
    channel is an electrode, and the pulse goes to each neuron the electrode stimulates
    (``stim_neuron[stim_indptr[c]:stim_indptr[c + 1]]``), else to neuron ``channel``.
    Among equal starts the pending pulses come first. Nothing is changed in place.

    Parameters
    ----------
    p_neuron, p_current, p_start, p_end : int64[m], float64[m], int64[m], int64[m]
        The pending pulses: target neuron, current (model units), first step and the step
        after the last, sorted by first step.
    channel, amplitude_ua, width_ms, onset_ms : uint32[n], float32[n], float32[n], float32[n]
        The new pulses: channel, amplitude (µA), width and onset (ms, from ``step``).
    step : int64
        The step the onsets count from.
    dt : float64
        The time step, in ms.
    current_per_ua : float64
        Model current per µA of amplitude.
    n_channels : int64
        Channels there are (neurons, or electrodes with ``mea``).
    stim_indptr, stim_neuron : int64[n_channels + 1], int64
        CSR of the neurons each electrode stimulates; read only with ``mea``.
    mea : bool
        Whether channels are electrodes.

    Returns
    -------
    top : int64
        -1, or the first channel not below ``n_channels`` (and then no pulses at all).
    pulses : tuple of ndarray
        ``(neuron, current, start, end)``, as the pending ones.
    """
    n = channel.size
    for i in range(n):
        if channel[i] >= n_channels:
            return np.int64(channel[i]), _none()
    m = 0
    for i in range(n):
        m += stim_indptr[channel[i] + 1] - stim_indptr[channel[i]] if mea else 1
    old = p_neuron.size
    neuron = np.empty(old + m, np.int64)
    current = np.empty(old + m, np.float64)
    start = np.empty(old + m, np.int64)
    end = np.empty(old + m, np.int64)
    neuron[:old], current[:old], start[:old], end[:old] = p_neuron, p_current, p_start, p_end
    j = old
    for i in range(n):
        first = step + np.int64(np.rint(np.float64(onset_ms[i]) / dt))
        last = first + np.int64(np.rint(np.float64(width_ms[i]) / dt))
        amps = np.float64(amplitude_ua[i]) * current_per_ua
        c = np.int64(channel[i])
        lo, hi = (stim_indptr[c], stim_indptr[c + 1]) if mea else (c, c + 1)
        for q in range(lo, hi):
            neuron[j] = stim_neuron[q] if mea else c
            current[j], start[j], end[j] = amps, first, last
            j += 1
    for i in range(1, old + m):
        if start[i] < start[i - 1]:
            order = np.argsort(start, kind="mergesort")  # stable: older first among equals
            return np.int64(-1), (neuron[order], current[order], start[order], end[order])
    return np.int64(-1), (neuron, current, start, end)


@njit([(_I8, _F8, _I8, _I8, types.int64)], cache=True)
def alive_after(p_neuron, p_current, p_start, p_end, k):
    """The pending pulses that end after step ``k``, in order.

    Parameters
    ----------
    p_neuron, p_current, p_start, p_end : int64[m], float64[m], int64[m], int64[m]
        The pending pulses, as `scheduled` returns them (``p_end``: the step after the last).
    k : int64
        The step; a pulse with ``p_end <= k`` is dropped.

    Returns
    -------
    changed : bool
        Whether any pulse was dropped.
    pulses : tuple of ndarray
        ``(neuron, current, start, end)`` kept; empty arrays when ``changed`` is False (the
        input then stands).
    """
    kept = 0
    for i in range(p_end.size):
        if p_end[i] > k:
            kept += 1
    if kept == p_end.size:
        return False, _none()
    neuron = np.empty(kept, np.int64)
    current = np.empty(kept, np.float64)
    start = np.empty(kept, np.int64)
    end = np.empty(kept, np.int64)
    j = 0
    for i in range(p_end.size):
        if p_end[i] > k:
            neuron[j], current[j] = p_neuron[i], p_current[i]
            start[j], end[j] = p_start[i], p_end[i]
            j += 1
    return True, (neuron, current, start, end)
