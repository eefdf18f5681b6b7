"""The device facts, and the simulators built on them."""

import numpy as np

from devices import khepera, mea
from sim_network.config import MeaConfig
from sim_network.mea import electrode_positions
from sim_robot import ir_value, preset


def test_the_mcs60_layout_is_an_8_by_8_grid_without_corners_named_12_to_87():
    assert mea.MCS60_NAMES.size == mea.MCS60_N == 60
    assert mea.MCS60_NAMES.min() == 12 and mea.MCS60_NAMES.max() == 87
    assert not {11, 18, 81, 88} & set(mea.MCS60_NAMES.tolist())
    assert len(set(mea.MCS60_NAMES.tolist())) == 60
    assert {21, 28, 71, 78, 12, 17, 82, 87} <= set(mea.MCS60_NAMES.tolist())


def test_the_simulated_mea_defaults_to_the_mcs60_layout():
    cfg = MeaConfig()
    assert (cfg.rows, cfg.cols, cfg.pitch_um) == (
        mea.MCS60_ROWS,
        mea.MCS60_COLS,
        mea.MCS60_PITCH_UM,
    )
    x, y = electrode_positions(cfg, 0.0, 0.0)
    assert x.size == mea.MCS60_N
    # name = column digit, row digit: x grows with the column, y with the row
    col = mea.MCS60_NAMES // 10 - 1
    row = mea.MCS60_NAMES % 10 - 1
    np.testing.assert_allclose(x, (col - 3.5) * mea.MCS60_PITCH_UM)
    np.testing.assert_allclose(y, (row - 3.5) * mea.MCS60_PITCH_UM)


def test_the_khepera2_preset_is_the_real_robot():
    body = preset("khepera2")
    assert body.radius_m == khepera.KHEPERA2_RADIUS_M
    assert body.wheel_base_m == khepera.KHEPERA2_WHEEL_BASE_M
    assert body.max_wheel_mps == 127 * 0.008
    np.testing.assert_allclose(body.sensor_offsets_m, khepera.KHEPERA2_SENSOR_POSITIONS_M)
    np.testing.assert_allclose(
        np.rad2deg(body.sensor_angles_rad), khepera.KHEPERA2_SENSOR_FACINGS_DEG, atol=1e-5
    )


def test_the_simulated_ir_response_passes_through_the_published_points():
    table = khepera.KHEPERA2_IR_TABLE
    np.testing.assert_allclose(ir_value(table[:, 0]), table[:, 1])
    assert ir_value(0.0) == khepera.IR_MAX_VALUE
