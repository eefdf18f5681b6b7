"""The calibration statistics are hub.analysis's, fed with the culture's neurons and layout."""

import numpy as np
import pytest

from hub.analysis.metrics import compute_metrics
from lab.activity import analyze_culture, summarize
from sim_network import Spikes, load_config
from sim_network.layout import build_layout


def _layout():
    cfg = load_config("configs/culture_1024.toml")
    return build_layout(cfg.layout, np.random.default_rng(0))


def _planted_network_burst(layout, start_ms, duration_ms, fraction=0.4):
    """`fraction` of all neurons burst from start_ms to start_ms + duration_ms (5 ms ISI)."""
    n_burst = int(fraction * layout.n)
    t_one = np.arange(start_ms, start_ms + duration_ms + 1e-9, 5.0)
    ch = np.repeat(np.arange(n_burst), t_one.size)
    t = np.tile(t_one, n_burst)
    order = np.argsort(t, kind="stable")
    return Spikes(ch[order].astype(np.uint32), t[order])


def test_summary_is_hub_analysis_on_neuron_channels_with_layout_cell_types():
    layout = _layout()
    sp = _planted_network_burst(layout, 1_000.0, 60.0)
    m = summarize(sp, layout, 0.0, 10_000.0)
    ref = compute_metrics(
        sp.channel, sp.t_ms, layout.n, 0.0, 10_000.0, layout.cell_type, layout.x_um, layout.y_um
    )
    assert m == ref
    assert m["n_network_bursts"] == 1
    # the duration is the network burst's extent (first to last participating spike)
    assert m["nb_duration_ms"] == pytest.approx(60.0)
    exc = layout.cell_type[: int(0.4 * layout.n)] == 0
    assert m["nb_exc_spike_fraction"] == pytest.approx(exc.mean())


def test_stimulus_times_give_the_psth_and_the_evoked_split():
    layout = _layout()
    sp = _planted_network_burst(layout, 1_050.0, 40.0)
    res = analyze_culture(sp, layout, 0.0, 5_000.0, stim_ms=[1_000.0, 3_000.0])
    assert res.evoked.tolist() == [True]
    assert 50.0 <= res.metrics["psth_peak_ms"] <= 90.0
