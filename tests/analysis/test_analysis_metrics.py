"""The metrics dict on a planted record with known answers."""

import json

import numpy as np
import pytest

from hub.analysis.metrics import AnalysisParams, analyze, compute_metrics
from hub.analysis.spikes import AnalysisInputError
from tests.analysis.analysis_synth import merge, network_burst, sparse_background

N = 10
T_STOP_MS = 60_000.0
NB_STARTS_MS = [5_000.0, 15_000.0, 25_000.0, 35_000.0, 45_000.0, 55_000.0]
X_UM = 100.0 * (np.arange(N) % 5)
Y_UM = 100.0 * (np.arange(N) // 5)


def _record():
    """Channels 0-4 burst together for 70 ms six times; channels 5-9 fire sparsely at 2 Hz."""
    bg_ch, bg_t = sparse_background(5, T_STOP_MS, rate_hz=2.0, seed=1)
    trains = [(bg_ch + 5, bg_t)] + [network_burst(range(5), s, 70.0) for s in NB_STARTS_MS]
    return merge(*trains)


def test_planted_record_gives_known_rates_and_burst_statistics():
    ch, t = _record()
    cell_type = np.array([0] * 5 + [1] * 5, dtype=np.uint8)
    m = compute_metrics(ch, t, N, 0.0, T_STOP_MS, cell_type=cell_type)
    per_channel = np.bincount(ch, minlength=N) / 60.0
    assert m["n_spikes"] == t.size
    assert m["mfr_hz"] == pytest.approx(per_channel.mean())
    assert m["mfr_sd_hz"] == pytest.approx(per_channel.std())
    assert m["mfr_inh_hz"] == pytest.approx(per_channel[5:].mean())
    # network bursts hold channels 0-4 (excitatory) plus whatever 5-9 fire by chance in them
    in_nb = np.zeros(t.size, dtype=bool)
    for s in NB_STARTS_MS:
        in_nb |= (t >= s) & (t <= s + 70.0)
    expected = np.mean(cell_type[ch[in_nb]] == 0)
    assert m["nb_exc_spike_fraction"] == pytest.approx(expected)
    assert m["nb_exc_spike_fraction"] > 0.9
    assert m["n_bursts"] == 30
    assert m["mbr_per_min"] == pytest.approx(3.0)  # 30 bursts / 10 channels / 1 min
    assert m["n_network_bursts"] == 6
    assert m["mnbr_per_min"] == pytest.approx(6.0)
    assert m["nb_duration_ms"] == pytest.approx(70.0)
    assert m["nb_duration_sd_ms"] == pytest.approx(0.0)
    assert m["nb_participation"] == pytest.approx(0.5)
    assert m["ibi_mean_ms"] == pytest.approx(10_000.0)
    assert m["ibi_cv"] == pytest.approx(0.0)
    json.dumps(m, allow_nan=False)  # JSON-ready


def test_two_network_bursts_give_an_interval_but_no_cv():
    # one interval says nothing of periodicity; the report said "CV 0 (0: periodic)"
    ch, t = merge(*[network_burst(range(5), s, 70.0) for s in NB_STARTS_MS[:2]])
    m = compute_metrics(ch, t, N, 0.0, T_STOP_MS)
    assert m["n_network_bursts"] == 2 and m["ibi_mean_ms"] == pytest.approx(10_000.0)
    assert m["ibi_cv"] is None


def test_stimuli_give_psth_peak_evoked_split_and_cat_spreads():
    ch, t = _record()
    stim = np.array(NB_STARTS_MS[:3]) - 60.0  # the first three network bursts are "evoked"
    params = AnalysisParams(psth_window_ms=(0.0, 200.0), psth_bin_ms=10.0)
    res = analyze(ch, t, N, 0.0, T_STOP_MS, x_um=X_UM, y_um=Y_UM, stim_ms=stim, params=params)
    m = res.metrics
    assert 60.0 <= m["psth_peak_ms"] <= 130.0
    assert m["n_evoked_nb"] == 3 and res.evoked.tolist() == [True] * 3 + [False] * 3
    assert len(res.cats) == 6
    # identical network bursts -> identical CATs -> zero spread
    assert m["cat_spread"] == pytest.approx(0.0, abs=1e-9)
    assert m["cat_spread_evoked"] == pytest.approx(0.0, abs=1e-9)


def test_empty_record_gives_zeros_and_nones_not_errors():
    m = compute_metrics([], [], 4, 0.0, 1_000.0, x_um=np.zeros(4), y_um=np.zeros(4), stim_ms=[])
    assert m["mfr_hz"] == 0.0 and m["n_bursts"] == 0 and m["mnbr_per_min"] == 0.0
    assert m["nb_duration_ms"] is None and m["cat_spread"] is None
    assert m["psth_peak_ms"] is None
    json.dumps(m, allow_nan=False)


def test_spikes_outside_the_span_are_ignored():
    m = compute_metrics([0, 0, 0], [-5.0, 500.0, 1_500.0], 1, 0.0, 1_000.0)
    assert m["n_spikes"] == 1 and m["mfr_hz"] == pytest.approx(1.0)


def test_params_from_config_dict_and_unknown_keys():
    p = AnalysisParams.from_dict(
        {"bursts": {"min_spikes": 4}, "network_bursts": {"min_fraction": 0.5}, "psth_bin_ms": 2}
    )
    assert p.bursts.min_spikes == 4 and p.network_bursts.min_fraction == 0.5
    assert p.psth_bin_ms == 2
    assert AnalysisParams.from_dict(p.to_dict()) == p
    with pytest.raises(AnalysisInputError, match="analysis.bogus"):
        AnalysisParams.from_dict({"bogus": 1})
    with pytest.raises(AnalysisInputError, match="analysis.bursts.size"):
        AnalysisParams.from_dict({"bursts": {"size": 1}})
