"""Single-channel bursts: at least 3 spikes within 20 ms, merged while dense."""

import numpy as np
import pytest

from hub.analysis.bursts import BURST_DTYPE, BurstParams, bursting_rate_per_min, detect_bursts
from hub.analysis.spikes import AnalysisInputError
from tests.analysis.analysis_synth import merge


def test_planted_burst_is_found_with_start_end_and_count():
    ch, t = merge(([0, 0, 0, 0], [100.0, 105.0, 112.0, 118.0]), ([1, 1], [50.0, 300.0]))
    b = detect_bursts(ch, t)
    assert b.dtype == BURST_DTYPE
    assert b.tolist() == [(0, 100.0, 118.0, 4)]


def test_three_spikes_spanning_more_than_window_are_not_a_burst():
    assert detect_bursts([0, 0, 0], [0.0, 10.0, 20.5]).size == 0
    # exactly 20 ms is within the window
    assert detect_bursts([0, 0, 0], [0.0, 10.0, 20.0]).size == 1


def test_dense_runs_merge_into_one_burst():
    # (0,8,16) and (8,16,24) both span <= 20 ms: one burst of 4 spikes
    b = detect_bursts([0] * 4, [0.0, 8.0, 16.0, 24.0])
    assert b[["start_ms", "end_ms", "n_spikes"]].tolist() == [(0.0, 24.0, 4)]


def test_a_spike_in_no_dense_triple_ends_the_burst_even_after_a_short_interval():
    # 28 is 18 ms after 10, but every triple holding it spans > 20 ms: it is not in a burst
    t = [0.0, 5.0, 10.0, 28.0, 47.0, 50.0, 53.0]
    b = detect_bursts([0] * 7, t)
    assert b[["start_ms", "end_ms", "n_spikes"]].tolist() == [(0.0, 10.0, 3), (47.0, 53.0, 3)]


def test_a_long_interval_ends_the_burst():
    t = [0.0, 5.0, 10.0, 31.0, 35.0, 40.0]
    b = detect_bursts([0] * 6, t)
    assert b[["start_ms", "end_ms", "n_spikes"]].tolist() == [(0.0, 10.0, 3), (31.0, 40.0, 3)]


def test_bursts_at_the_edges_of_the_record_are_kept():
    ch, t = merge(([0, 0, 0], [0.0, 1.0, 2.0]), ([1, 1, 1], [998.0, 999.0, 999.9]))
    b = detect_bursts(ch, t)
    assert b.tolist() == [(0, 0.0, 2.0, 3), (1, 998.0, 999.9, 3)]


def test_interleaved_channels_are_separated():
    # channels 0 and 1 alternate; each alone has 3 spikes within 20 ms only on channel 0
    ch = [0, 1, 0, 1, 0, 1]
    t = [0.0, 1.0, 5.0, 30.0, 10.0, 60.0]
    order = np.argsort(t, kind="stable")
    b = detect_bursts(np.array(ch)[order], np.array(t)[order])
    assert b.tolist() == [(0, 0.0, 10.0, 3)]


def test_thresholds_are_configurable():
    t = [0.0, 10.0, 20.0, 30.0]
    assert detect_bursts([0] * 4, t, BurstParams(min_spikes=4, window_ms=30.0)).size == 1
    assert detect_bursts([0] * 4, t, BurstParams(min_spikes=4, window_ms=29.0)).size == 0
    # a tighter max ISI splits the run; pieces shorter than min_spikes are dropped
    p = BurstParams(min_spikes=2, window_ms=20.0, max_isi_ms=5.0)
    assert detect_bursts([0] * 4, [0.0, 3.0, 13.0, 15.0], p).tolist() == [
        (0, 0.0, 3.0, 2),
        (0, 13.0, 15.0, 2),
    ]


def test_no_spikes_and_too_few_spikes_give_no_bursts():
    assert detect_bursts([], []).size == 0
    assert detect_bursts(np.array([], np.uint32), np.array([])).dtype == BURST_DTYPE
    assert detect_bursts([3, 3], [0.0, 1.0]).size == 0


def test_bad_input_is_named():
    with pytest.raises(AnalysisInputError, match="sorted"):
        detect_bursts([0, 0, 0], [2.0, 1.0, 3.0])
    with pytest.raises(AnalysisInputError, match="equal length"):
        detect_bursts([0, 0], [1.0])
    with pytest.raises(AnalysisInputError, match="bursts.min_spikes"):
        BurstParams(min_spikes=1)
    with pytest.raises(AnalysisInputError, match="bursts.window_ms"):
        BurstParams(window_ms=-1.0)


def test_bursting_rate_counts_silent_channels_as_zero():
    b = detect_bursts([2, 2, 2], [0.0, 1.0, 2.0])
    rate = bursting_rate_per_min(b, n_channels=4, duration_ms=30_000.0)
    assert rate.tolist() == [0.0, 0.0, 2.0, 0.0]
