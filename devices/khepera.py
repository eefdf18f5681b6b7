"""Khepera robots: body geometry, wheel-speed units and the IR proximity calibration.

Body frame: x forward, y to the left; angles counter-clockwise from forward. Lengths in
metres, angles in degrees where the manuals give degrees.
"""

from __future__ import annotations

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

# ----------------------------------------------------------------------------- Khepera IV

#: body radius
KHEPERA4_RADIUS_M = 0.0704
#: distance between the wheels
KHEPERA4_WHEEL_BASE_M = 0.1054
#: wheel radius
KHEPERA4_WHEEL_RADIUS_M = 0.021
#: facing of each of the 8 IR sensors: evenly spaced from forward, counter-clockwise
KHEPERA4_SENSOR_FACINGS_DEG = np.arange(8) * 45.0
