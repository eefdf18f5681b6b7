"""Khepera robots: body geometry, wheel-speed units and the IR proximity calibration.

Body frame: x forward, y to the left; angles counter-clockwise from forward. Lengths in
metres, angles in degrees where the manuals give degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# ----------------------------------------------------------------------------- Khepera II

#: body radius (70 mm diameter)
KHEPERA2_RADIUS_M = 0.035
#: distance between the wheels (manuals give 52-53 mm)
KHEPERA2_WHEEL_BASE_M = 0.053
#: wheel radius
KHEPERA2_WHEEL_RADIUS_M = 0.0075
#: one unit of the ``D`` command's wheel speed (pulses per 10 ms) is 8 mm/s
KHEPERA2_SPEED_UNIT_MPS = 0.008
#: the ``D`` command's speeds lie in -127..127 units
KHEPERA2_MAX_SPEED_UNITS = 127
#: the fastest wheel speed (127 units x 8 mm/s = 1.016 m/s)
KHEPERA2_MAX_WHEEL_MPS = KHEPERA2_MAX_SPEED_UNITS * KHEPERA2_SPEED_UNIT_MPS
#: distance travelled per encoder pulse
KHEPERA2_PULSE_M = 0.08e-3
#: position of each of the 8 IR sensors in the body frame (m), in the order ``N`` reports them
KHEPERA2_SENSOR_POSITIONS_M = 1e-3 * np.array(
    [(10, 24), (19, 17), (25, 6), (25, -6), (19, -17), (10, -24), (-24, -10), (-24, 10)],
    dtype=np.float64,
)
#: facing of each IR sensor (deg, counter-clockwise from forward); some models tilt 2 and 3 by
#: +-10 deg
KHEPERA2_SENSOR_FACINGS_DEG = np.array([90, 45, 0, 0, -45, -90, 180, 180], dtype=np.float64)
#: the largest IR proximity value (an obstacle at 8 mm or nearer)
IR_MAX_VALUE = 1023
#: one published IR calibration: (distance_m, value) points, nearest first; higher = nearer;
#: the sensor's noise floor is about 10-100 counts, so beyond 100 mm it sees nothing useful
KHEPERA2_IR_TABLE = np.array(
    [
        (0.000, 1023.0),
        (0.008, 1023.0),
        (0.010, 1000.0),
        (0.020, 450.0),
        (0.030, 275.0),
        (0.040, 190.0),
        (0.050, 150.0),
        (0.060, 125.0),
        (0.070, 110.0),
        (0.080, 100.0),
        (0.090, 90.0),
        (0.100, 80.0),
    ]
)

# ----------------------------------------------------------------------------- Khepera III
# The serial protocol's facts are from K-Team's Khepera III user manual (v2.2): section 3.2.1
# (speed) and the command list (D, N, R, I). The sensor geometry is that of Cyberbotics'
# Webots model of the robot (Khepera3.proto), as the manual gives it only as a figure.

#: body radius (the Webots model's outline; about 130 mm across)
KHEPERA3_RADIUS_M = 0.064
#: distance between the wheels
KHEPERA3_WHEEL_BASE_M = 0.0885
#: wheel radius (the manual's wheel circumference, 128.8 mm)
KHEPERA3_WHEEL_RADIUS_M = 0.0205
#: one unit of the ``D`` command's speed: the manual's "RealSpeed = MotorSpeed / 144.01" mm/s
KHEPERA3_SPEED_UNIT_MPS = 1e-3 / 144.01
#: the fastest speed under the speed regulation (43,000 units, 298 mm/s; the manual)
KHEPERA3_MAX_SPEED_UNITS = 43_000
#: distance travelled per encoder pulse (encoder resolution x4, the default)
KHEPERA3_PULSE_M = 0.047e-3
#: position of each of the 9 IR sensors around the body (m), in the order ``N`` reports them:
#: back left, left 90, left 45, front left, front right, right 45, right 90, back right, back
KHEPERA3_SENSOR_POSITIONS_M = np.array(
    [
        (-0.04038, 0.04956),
        (0.01481, 0.06296),
        (0.04885, 0.04538),
        (0.06560, 0.01552),
        (0.06560, -0.01552),
        (0.04885, -0.04538),
        (0.01481, -0.06296),
        (-0.04038, -0.04956),
        (-0.05502, 0.0),
    ],
    dtype=np.float64,
)
#: facing of each IR sensor (deg): outward from the centre through the sensor (the Webots
#: model's own facings agree within 0.1 deg, but for the back-right sensor's -140.8)
KHEPERA3_SENSOR_FACINGS_DEG = np.degrees(
    np.arctan2(KHEPERA3_SENSOR_POSITIONS_M[:, 1], KHEPERA3_SENSOR_POSITIONS_M[:, 0])
)
#: the IR sensors' useful range
KHEPERA3_IR_RANGE_M = (0.02, 0.2)

# ----------------------------------------------------------------------------- Khepera IV

#: body radius
KHEPERA4_RADIUS_M = 0.0704
#: distance between the wheels
KHEPERA4_WHEEL_BASE_M = 0.1054
#: wheel radius
KHEPERA4_WHEEL_RADIUS_M = 0.021
#: facing of each of the 8 IR sensors: evenly spaced from forward, counter-clockwise
KHEPERA4_SENSOR_FACINGS_DEG = np.arange(8) * 45.0


# ----------------------------------------------------------------------------- the models


@dataclass(frozen=True)
class KheperaModel:
    """What an adapter needs to know of one Khepera model: its serial line as it leaves the
    factory, its dialect's units and its body. ``ir_table`` is None where no calibration is
    published (a lab measures one)."""

    dialect: str
    name: str
    baud: int
    stop_bits: int
    radius_m: float
    wheel_base_m: float
    speed_unit_mps: float
    max_speed_units: int
    pulse_m: float
    sensor_positions_m: np.ndarray
    sensor_facings_deg: np.ndarray
    ir_table: np.ndarray | None

    @property
    def max_wheel_mps(self) -> float:
        """The fastest a wheel turns, in m/s (``max_speed_units`` in the dialect's units)."""
        return self.speed_unit_mps * self.max_speed_units


#: by the name of their serial dialect (``body.params.dialect``)
MODELS = {
    "khepera2": KheperaModel(
        "khepera2",
        "Khepera II",
        9600,
        2,
        KHEPERA2_RADIUS_M,
        KHEPERA2_WHEEL_BASE_M,
        KHEPERA2_SPEED_UNIT_MPS,
        KHEPERA2_MAX_SPEED_UNITS,
        KHEPERA2_PULSE_M,
        KHEPERA2_SENSOR_POSITIONS_M,
        KHEPERA2_SENSOR_FACINGS_DEG,
        KHEPERA2_IR_TABLE[1:],  # from 8 mm: nearer is not resolved
    ),
    "khepera3": KheperaModel(
        "khepera3",
        "Khepera III",
        115200,
        1,  # 8N1
        KHEPERA3_RADIUS_M,
        KHEPERA3_WHEEL_BASE_M,
        KHEPERA3_SPEED_UNIT_MPS,
        KHEPERA3_MAX_SPEED_UNITS,
        KHEPERA3_PULSE_M,
        KHEPERA3_SENSOR_POSITIONS_M,
        KHEPERA3_SENSOR_FACINGS_DEG,
        None,
    ),
}
