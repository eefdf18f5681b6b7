"""Firing rates, ISIs, PSTH and instantaneous rate on hand-made trains."""

import numpy as np
import pytest

from hub.analysis.spikes import (
    AnalysisInputError,
    firing_rates_hz,
    instantaneous_rate,
    interval_histogram,
    isi_ms,
    psth,
)
from tests.analysis.analysis_synth import merge


def test_firing_rates_per_channel_over_the_span():
    ch, t = merge(([0] * 10, np.arange(10) * 100.0), ([2] * 5, np.arange(5) * 100.0))
    rates = firing_rates_hz(ch, t, n_channels=3, t_start_ms=0.0, t_stop_ms=2_000.0)
    assert rates.tolist() == [5.0, 0.0, 2.5]


def test_isi_are_within_channels_only():
    ch, t = merge(([0, 0, 0], [0.0, 10.0, 30.0]), ([1, 1], [5.0, 6.0]))
    assert sorted(isi_ms(ch, t).tolist()) == [1.0, 10.0, 20.0]
    assert isi_ms([], []).size == 0
    counts, edges = interval_histogram([1.0, 10.0, 20.0], bin_ms=5.0, max_ms=25.0)
    assert counts.tolist() == [1, 0, 1, 0, 1] and edges[-1] == 25.0


def test_psth_peak_at_the_planted_latency():
    rng = np.random.default_rng(3)
    stim = np.arange(1_000.0, 60_000.0, 5_000.0)
    background = (rng.integers(0, 8, 3_000), rng.uniform(0, 61_000.0, 3_000))
    evoked = (np.tile(np.arange(8), stim.size), np.repeat(stim + 62.0, 8))  # all 8, +62 ms
    ch, t = merge(background, evoked)
    h = psth(ch, t, stim, n_channels=8, window_ms=(-50.0, 200.0), bin_ms=5.0)
    assert h.peak_latency_ms() == pytest.approx(62.5)
    assert h.counts.sum() >= 8 * stim.size
    assert h.n_stimuli == stim.size
    # the evoked bin holds one spike per channel per stimulus: at least 1 / 5 ms = 200 Hz
    assert h.rate_hz.max() >= 200.0


def test_psth_with_no_spikes_or_no_stimuli():
    h = psth([], [], [100.0], n_channels=4)
    assert h.counts.sum() == 0 and np.isnan(h.peak_latency_ms())
    h = psth([0], [5.0], [], n_channels=4)
    assert h.counts.sum() == 0


def test_instantaneous_rate_for_all_exc_and_inh():
    cell_type = np.array([0, 0, 1], dtype=np.uint8)
    ch, t = merge(([0, 1], [5.0, 6.0]), ([2, 2, 2], [15.0, 16.0, 17.0]))
    centers, rate = instantaneous_rate(ch, t, 3, 0.0, 20.0, bin_ms=10.0)
    assert centers.tolist() == [5.0, 15.0] and rate.tolist() == [200.0, 300.0]
    _, exc = instantaneous_rate(ch, t, 3, 0.0, 20.0, 10.0, "exc", cell_type)
    _, inh = instantaneous_rate(ch, t, 3, 0.0, 20.0, 10.0, "inh", cell_type, per_channel=True)
    assert exc.tolist() == [200.0, 0.0] and inh.tolist() == [0.0, 300.0]
    with pytest.raises(AnalysisInputError, match="cell_type"):
        instantaneous_rate(ch, t, 3, 0.0, 20.0, 10.0, "exc")
    with pytest.raises(AnalysisInputError, match="population"):
        instantaneous_rate(ch, t, 3, 0.0, 20.0, 10.0, "glia", cell_type)


def test_bad_spans_and_channels_are_named():
    with pytest.raises(AnalysisInputError, match="t_stop_ms must be > t_start_ms"):
        firing_rates_hz([0], [1.0], 1, 10.0, 10.0)
    with pytest.raises(AnalysisInputError, match="channel must be < n_channels=2"):
        firing_rates_hz([5], [1.0], 2, 0.0, 10.0)
    with pytest.raises(AnalysisInputError, match="finite"):
        isi_ms([0, 0], [1.0, np.nan])


def test_psth_restricted_to_some_channels():
    ch, t = merge(
        ([0, 1, 1], [110.0, 120.0, 121.0]),
    )
    h = psth(ch, t, [100.0], n_channels=4, window_ms=(0.0, 50.0), bin_ms=10.0, channels=[1])
    assert h.counts.tolist() == [0, 0, 2, 0, 0] and h.n_channels == 1
    assert h.peak_latency_ms() == 25.0
    assert np.isnan(h.peak_latency_ms(min_latency_ms=30.0))  # nothing after 30 ms
