"""Center of Activity and CA trajectories."""

import numpy as np
import pytest

from hub.analysis.center_of_activity import (
    Cat,
    cat_spread,
    center_of_activity,
    center_of_activity_trajectories,
)
from hub.analysis.network_bursts import NetworkBursts
from tests.analysis.analysis_synth import merge

# a 3 x 3 grid, 100 um pitch: channel c at (100 * (c % 3), 100 * (c // 3))
X_UM = 100.0 * (np.arange(9) % 3)
Y_UM = 100.0 * (np.arange(9) // 3)


def test_ca_is_the_rate_weighted_mean_position():
    # channel 0 (0,0) fires once, channel 8 (200,200) fires 3 times in the window
    ch, t = merge(([0], [1.0]), ([8, 8, 8], [2.0, 3.0, 4.0]))
    x, y, n = center_of_activity(ch, t, X_UM, Y_UM, [0.0], 10.0)
    assert (x[0], y[0], n[0]) == (150.0, 150.0, 4)


def test_ca_window_is_open_at_start_closed_at_end_and_empty_is_nan():
    ch, t = merge(
        ([4], [10.0]),
    )
    x, _, n = center_of_activity(ch, t, X_UM, Y_UM, [10.0, 0.0, 20.0], 10.0)
    assert n.tolist() == [0, 1, 0]
    assert np.isnan(x[0]) and x[1] == 100.0 and np.isnan(x[2])


def test_cat_follows_activity_moving_across_the_grid():
    # activity sweeps from channel 0 (0,0) to channel 8 (200,200) over 100 ms
    ch, t = merge(([0] * 10, np.arange(0.0, 50.0, 5.0)), ([8] * 10, np.arange(50.0, 100.0, 5.0)))
    nbs = NetworkBursts(np.array([0.0]), np.array([100.0]), [np.array([0, 8], np.uint32)])
    (cat,) = center_of_activity_trajectories(ch, t, X_UM, Y_UM, nbs, time_scale_ms=20.0)
    assert cat.t_ms[0] == 0.0 and cat.t_ms[-1] == 100.0
    assert (cat.x_um[0], cat.y_um[0]) == (0.0, 0.0)
    assert (cat.x_um[-1], cat.y_um[-1]) == (200.0, 200.0)
    assert np.all(np.diff(cat.x_um) >= 0)  # monotone path from one corner to the other


def test_cat_spread_is_zero_for_identical_paths_and_known_for_shifted_ones():
    t = np.array([0.0, 10.0, 20.0])
    a = Cat(t, np.array([0.0, 50.0, 100.0]), np.zeros(3))
    b = Cat(t * 2, np.array([0.0, 50.0, 100.0]), np.zeros(3))  # same path, slower
    c = Cat(t, np.array([0.0, 50.0, 100.0]), np.full(3, 30.0))  # shifted by 30 um
    assert cat_spread([a, b]) == pytest.approx(0.0)
    assert cat_spread([a, c]) == pytest.approx(30.0)
    assert cat_spread([a, b, c]) == pytest.approx((0.0 + 30.0 + 30.0) / 3)
    assert np.isnan(cat_spread([a]))
    assert np.isnan(cat_spread([a, Cat(np.empty(0), np.empty(0), np.empty(0))]))
