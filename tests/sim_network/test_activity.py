"""Calibration statistics follow the paper's definitions of bursts and network bursts."""

import numpy as np
import pytest

from sim_network.activity import find_bursts, network_bursts, psth, summarize


def test_three_spikes_within_20_ms_make_one_burst_and_overlaps_merge():
    neuron = np.array([0, 0, 0, 0, 1, 1, 1, 2, 2, 2])
    t = np.array([100.0, 105, 110, 118, 0, 15, 30, 50, 60, 70.0])
    b = find_bursts(neuron, t)
    # neuron 0: windows (100,110) and (105,118) merge into one burst 100–118
    # neuron 1: 30 ms for three spikes: no burst; neuron 2: exactly 20 ms: a burst
    assert list(b.neuron) == [0, 2]
    assert list(b.start_ms) == [100.0, 50.0]
    assert list(b.end_ms) == [118.0, 70.0]


def test_network_burst_needs_thirty_percent_bursting_together():
    n = 10
    # neurons 0-2 burst at 100-110 ms (30 %), neurons 0-1 at 500-510 ms (20 %)
    neuron = np.repeat([0, 1, 2, 0, 1], 3)
    t = np.concatenate([[100.0, 105, 110]] * 3 + [[500.0, 505, 510]] * 2)
    start, end = network_bursts(find_bursts(neuron, t), n, 1000.0)
    assert list(start) == [100.0]
    assert end[0] == pytest.approx(111.0)


def test_summary_rates_and_excitatory_share():
    cell_type = np.array([0, 0, 0, 1])
    neuron = np.array([0, 1, 2, 3, 3, 3, 3])
    t = np.array([100.0, 101, 102, 103, 104, 105, 900])
    s = summarize(neuron, t, cell_type, 0.0, 1000.0)
    assert s.mfr_mean == pytest.approx(7 / 4)
    assert s.mfr_exc == pytest.approx(1.0) and s.mfr_inh == pytest.approx(4.0)
    assert s.mbr_per_min == pytest.approx(1 / 4 * 60)  # one burst (neuron 3) in 1 s, 4 neurons
    assert s.n_network_bursts == 0  # one bursting neuron of four is 25 % < 30 %


def test_psth_counts_per_trial():
    t = np.array([12.0, 13.0, 112.0, 250.0])
    edges, counts = psth(t, np.array([0.0, 100.0]), 50.0, 5.0)
    assert edges[2] == 10.0 and counts[2] == pytest.approx(1.5)
    assert counts.sum() == pytest.approx(1.5)
