"""Connectivity follows P = p_c_max · exp(-d / D_Pc); weights and delays follow the config."""

import numpy as np

from sim_network import ConnectivityConfig, LayoutConfig
from sim_network.connectivity import UM_PER_MS_PER_M_S, build_synapses, connection_probability
from sim_network.layout import build_layout

CON = ConnectivityConfig(p_c_max=0.6, d_pc_um=100.0, cutoff_um=400.0)


def built(rows=40, cols=40, con=CON, seed=3):
    rng = np.random.default_rng(seed)
    layout = build_layout(LayoutConfig(rows=rows, cols=cols, spacing_um=25.0), rng)
    return layout, build_synapses(layout, con, rng)


def test_measured_probability_matches_formula_at_each_distance():
    layout, syn = built()
    pre = syn.pre()
    # count, per distance, the ordered pairs that exist and those that connected
    x, y = layout.x_um.astype(np.float64), layout.y_um.astype(np.float64)
    d_all = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
    for d in (25.0, 25.0 * np.sqrt(2), 100.0, 200.0, 300.0):
        pairs = np.isclose(d_all, d).sum()
        made = np.isclose(np.hypot(x[pre] - x[syn.post], y[pre] - y[syn.post]), d).sum()
        p = CON.p_c_max * np.exp(-d / CON.d_pc_um)
        sd = np.sqrt(pairs * p * (1 - p))
        assert abs(made - pairs * p) < 4 * sd, (d, made, pairs * p)


def test_the_connection_probability_is_the_rule_up_to_the_cutoff_and_zero_beyond():
    d = np.array([0.0, 100.0, 400.0, 400.1, 1e4])
    p = connection_probability(d, CON)
    np.testing.assert_allclose(p[:3], 0.6 * np.exp(-d[:3] / 100.0))
    assert p[3] == 0.0 and p[4] == 0.0


def test_no_connections_beyond_cutoff_and_no_self_connections():
    _, syn = built()
    assert syn.distance_um.max() <= CON.cutoff_um
    assert np.all(syn.pre() != syn.post)


def test_weights_have_the_sign_of_the_presynaptic_type_and_stay_in_range():
    layout, syn = built()
    exc = layout.cell_type[syn.pre()] == 0
    w = syn.weight_mv
    assert np.all((w[exc] >= CON.weight_exc_mv[0]) & (w[exc] <= CON.weight_exc_mv[1]))
    assert np.all((w[~exc] >= CON.weight_inh_mv[0]) & (w[~exc] <= CON.weight_inh_mv[1]))
    assert w[exc].mean() > 0 > w[~exc].mean()


def test_delays_are_synaptic_delay_plus_distance_over_speed():
    _, syn = built()
    speed = syn.distance_um / ((syn.delay_ms - CON.synaptic_delay_ms) * UM_PER_MS_PER_M_S)
    assert speed.min() >= CON.speed_m_s[0] * 0.999
    assert speed.max() <= CON.speed_m_s[1] * 1.001
    # speeds are drawn uniformly: their mean is mid-range
    assert abs(speed.mean() - sum(CON.speed_m_s) / 2) < 0.02


def test_inhibitory_fraction_is_exact():
    layout, _ = built()
    assert (layout.cell_type == 1).sum() == round(0.2 * layout.n)


def test_same_seed_same_network_and_different_seed_differs():
    _, a = built(seed=5)
    _, b = built(seed=5)
    _, c = built(seed=6)
    assert np.array_equal(a.post, b.post) and np.array_equal(a.weight_mv, b.weight_mv)
    assert not np.array_equal(a.post, c.post)
