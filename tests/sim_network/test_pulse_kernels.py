"""Pulses scheduled in neuron space by the compiled kernels, against the rule written
plainly in numpy (how the network scheduled them before they were compiled)."""

from __future__ import annotations

import numpy as np
import pytest

from sim_network import pulse_kernels

DT_MS = 0.1
PER_UA = 0.5


def scheduled_plainly(pending, channel, amplitude, width, onset, step, indptr=None, neurons=None):
    """Each pulse on steps [step + rint(onset / dt), + rint(width / dt)), to the neurons of
    its electrode (or neuron ``channel``); all pending pulses stably sorted by start."""
    steps = np.rint(np.concatenate((onset, width)).astype(np.float64) / DT_MS).astype(np.int64)
    n = channel.size
    start = step + steps[:n]
    end = start + steps[n:]
    current = amplitude.astype(np.float64) * PER_UA
    neuron = channel.astype(np.int64)
    if indptr is not None:
        counts = np.diff(indptr)[neuron]
        idx = [np.arange(indptr[c], indptr[c + 1]) for c in neuron]
        neuron = neurons[np.concatenate(idx).astype(np.int64)] if idx else neuron[:0]
        start, end, current = (np.repeat(a, counts) for a in (start, end, current))
    new = (neuron, current, start, end)
    every = [np.concatenate((p, q)) for p, q in zip(pending, new, strict=True)]
    order = np.argsort(every[2], kind="stable")
    return tuple(a[order] for a in every)


def alive_plainly(pending, k):
    keep = pending[3] > k
    return tuple(a[keep] for a in pending)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("through_electrodes", [False, True])
def test_pulses_are_scheduled_and_dropped_as_the_plain_rule_does(seed, through_electrodes):
    rng = np.random.default_rng(seed)
    n_channels = 16
    indptr = np.concatenate(([0], np.cumsum(rng.integers(0, 4, n_channels)))).astype(np.int64)
    neurons = rng.integers(0, 100, indptr[-1]).astype(np.int64)
    none = np.zeros(0, np.int64)
    mine = plain = (none, np.zeros(0), none, none)
    for step in range(0, 4000, 100):  # 10 ms steps
        m = int(rng.integers(0, 9))
        channel = rng.integers(0, n_channels, m).astype(np.uint32)
        amplitude = rng.uniform(-20, 20, m).astype(np.float32)
        width = rng.choice([0.0, 0.2, 0.35, 25.0], m).astype(np.float32)
        onset = rng.choice([0.0, 0.05, 3.0, 9.95], m).astype(np.float32)  # ties and disorder
        top, mine = pulse_kernels.scheduled(
            *mine, channel, amplitude, width, onset, step, DT_MS, PER_UA, n_channels,
            indptr if through_electrodes else none, neurons if through_electrodes else none,
            through_electrodes,
        )  # fmt: skip
        assert top == -1
        args = (indptr, neurons) if through_electrodes else ()
        plain = scheduled_plainly(plain, channel, amplitude, width, onset, step, *args)
        for a, b in zip(mine, plain, strict=True):
            assert a.dtype == b.dtype and np.array_equal(a, b)
        changed, alive = pulse_kernels.alive_after(*mine, step + 50)
        mine = alive if changed else mine
        plain = alive_plainly(plain, step + 50)
        for a, b in zip(mine, plain, strict=True):
            assert np.array_equal(a, b)


def test_a_channel_out_of_range_is_named_and_nothing_scheduled():
    none = np.zeros(0, np.int64)
    channel = np.array([2, 16, 17], np.uint32)
    f4 = np.ones(3, np.float32)
    top, pulses = pulse_kernels.scheduled(
        none, np.zeros(0), none, none, channel, f4, f4, f4, 0, DT_MS, PER_UA, 16, none, none,
        False,
    )  # fmt: skip
    assert top == 16 and all(a.size == 0 for a in pulses)


def test_values_are_checked_in_arrays_of_any_layout():
    ok = np.array([1.0, 0.0, 2.0, 0.0], np.float32)
    assert pulse_kernels.values_ok(ok[::2], ok[::2], ok[::2])  # strided, writable
    for bad in (np.nan, np.inf, -1.0):
        values = np.array([1.0, bad], np.float32)
        assert not pulse_kernels.values_ok(ok[:2], values, ok[:2])
        assert not pulse_kernels.values_ok(ok[:2], ok[:2], values)
    assert pulse_kernels.values_ok(np.array([-3.0, 1.0], np.float32), ok[:2], ok[:2])
