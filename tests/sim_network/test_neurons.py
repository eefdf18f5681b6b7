"""Single-neuron behaviour of each model under a constant current (no noise, no synapses)."""

import numpy as np
import pytest

from sim_network import (
    AdaptationConfig,
    ConnectivityConfig,
    LayoutConfig,
    Network,
    NetworkConfig,
    NeuronConfig,
    NoiseConfig,
    Pulses,
    SlowCurrentConfig,
    StimulationConfig,
)


def lone_neuron(model="izhikevich", exc_type="RS", dt_ms=0.1, inhibitory=False):
    cfg = NetworkConfig(
        dt_ms=dt_ms,
        layout=LayoutConfig(rows=1, cols=1, inhibitory_fraction=1.0 if inhibitory else 0.0),
        # the named type exactly (the default culture spreads its cells' types)
        neurons=NeuronConfig(
            model=model, excitatory_type=exc_type, heterogeneity_exc=0.0, heterogeneity_inh=0.0
        ),
        connectivity=ConnectivityConfig(p_c_max=0.0),
        noise=NoiseConfig(sd=0.0, inhibitory_mean=None),
        stimulation=StimulationConfig(model_current_per_ua=1.0),  # pulse amplitude = current
        adaptation=AdaptationConfig(increment_exc_mv_per_ms=0.0),  # the published model
        slow_current=SlowCurrentConfig(share=0.0),
    )
    return Network(cfg, seed=0)


def spike_times(net, current, duration_ms=1000.0):
    net.run(duration_ms, pulses=Pulses.single([0], current, duration_ms))
    return net.neuron_spikes.t_ms


def test_regular_spiking_adapts_and_fast_spiking_does_not():
    rs = np.diff(spike_times(lone_neuron(), 10.0))
    fs = np.diff(spike_times(lone_neuron(inhibitory=True), 10.0))
    assert rs[-1] > 1.5 * rs[0]  # RS: inter-spike intervals lengthen (spike-frequency adaptation)
    assert 1000.0 / fs[-1] > 100.0  # FS: keeps firing above 100 Hz
    assert np.allclose(fs[5:], fs[-1], rtol=0.05)  # tonic after a few spikes
    assert fs.mean() < rs.mean() / 3


@pytest.mark.parametrize("dt_ms", [0.1, 1.0])
def test_izhikevich_rheobase_lies_near_four(dt_ms):
    # RS rest disappears at I = 4 (0.04 v² + 4.8 v + 140 + I = 0 loses its roots); a step from
    # rest already overshoots to spiking a little below that.
    assert spike_times(lone_neuron(dt_ms=dt_ms), 3.0, 2000.0).size == 0
    assert spike_times(lone_neuron(dt_ms=dt_ms), 4.5, 2000.0).size >= 10


@pytest.mark.parametrize(
    ("model", "currents"),
    [
        ("izhikevich", [5.0, 10.0, 20.0, 40.0]),
        ("lif", [16.0, 20.0, 30.0, 50.0]),
        ("hh", [8.0, 15.0, 30.0, 60.0]),
    ],
)
def test_f_i_curve_is_monotone(model, currents):
    rates = [spike_times(lone_neuron(model=model), i, 500.0).size * 2.0 for i in currents]
    assert rates[0] > 0
    assert all(b > a for a, b in zip(rates, rates[1:], strict=False)), rates


def test_lif_rheobase_and_rate_match_theory():
    # v_rest -65, threshold -50, R = 1, tau 20 ms: fires iff I > 15; period is analytic.
    assert spike_times(lone_neuron(model="lif"), 14.5).size == 0
    t = spike_times(lone_neuron(model="lif"), 30.0)
    period = 20.0 * np.log(30.0 / (30.0 - 15.0)) + 2.0  # plus 2 ms refractory
    assert np.diff(t).mean() == pytest.approx(period, abs=0.25)


def test_hh_is_silent_at_rest_and_fires_above_threshold():
    assert spike_times(lone_neuron(model="hh"), 0.0).size == 0
    t = spike_times(lone_neuron(model="hh"), 10.0)
    assert 40 < t.size < 120  # classic squid axon: ~ 60-70 Hz at 10 µA/cm²


def test_other_izhikevich_types_are_selectable():
    ib = np.diff(spike_times(lone_neuron(exc_type="CH"), 10.0, 300.0))
    # chattering: bursts of closely spaced spikes separated by longer pauses
    assert ib.min() < 0.3 * ib.max()
