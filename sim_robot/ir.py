"""Khepera-like infra-red response: distance (m) to a 0–1023 proximity value.

The table is the published Khepera II calibration (``shared/reference/devices.md``): higher
values mean nearer. Beyond its last point (80 at 100 mm) we assume a linear fall to 0 at
``IR_FADE_M`` (120 mm), so "nothing seen" reads 0 and not the 10–100 count noise floor of a
real sensor. Between points the value is linearly interpolated in distance.
"""

from __future__ import annotations

import numpy as np

#: (distance_m, value) points, nearest first
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
        (0.120, 0.0),
    ]
)
#: distance at which the modelled IR value reaches 0 (m)
IR_FADE_M = float(KHEPERA2_IR_TABLE[-1, 0])

IR_MODELS = {"khepera2": KHEPERA2_IR_TABLE}


def ir_value(range_m: np.ndarray, model: str = "khepera2") -> np.ndarray:
    """Map ranges (m) to IR proximity values (float32, 0–1023, higher = nearer).

    Parameters
    ----------
    range_m : array_like
        Distances from the sensor, metres (any shape).
    model : str
        Name of a table in ``IR_MODELS``.
    """
    try:
        table = IR_MODELS[model]
    except KeyError:
        raise ValueError(f"ir_model must be one of {sorted(IR_MODELS)}, got {model!r}") from None
    r = np.asarray(range_m, dtype=np.float64)
    return np.interp(r, table[:, 0], table[:, 1], right=0.0).astype(np.float32)
