"""Khepera-like infra-red response: distance (m) to a 0–1023 proximity value.

The table is the published Khepera II calibration (``devices.khepera.KHEPERA2_IR_TABLE``): higher
values mean nearer. Beyond its last point (80 at 100 mm) we assume a linear fall to 0 at
``IR_FADE_M`` (120 mm), so "nothing seen" reads 0 and not the 10–100 count noise floor of a
real sensor. Between points the value is linearly interpolated in distance.
"""

from __future__ import annotations

import numpy as np

from devices import khepera

#: (distance_m, value) points, nearest first: the published table and the assumed fade to 0
KHEPERA2_IR_TABLE = np.concatenate([khepera.KHEPERA2_IR_TABLE, [(0.120, 0.0)]])
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

    Returns
    -------
    float32 array
        Of the shape of ``range_m``: values interpolated in distance, 0 beyond the table.
    """
    try:
        table = IR_MODELS[model]
    except KeyError:
        raise ValueError(f"ir_model must be one of {sorted(IR_MODELS)}, got {model!r}") from None
    return table_value(range_m, table)


def table_value(range_m: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Map ranges (m) to IR values through a calibration table.

    Parameters
    ----------
    range_m : array_like
        Distances from the sensor, metres (any shape).
    table : float64[n, 2]
        ``(distance_m, value)`` points, nearest first.

    Returns
    -------
    float32 array
        Of the shape of ``range_m``: linear in distance between points, the first value
        nearer than the first point, 0 beyond the last.
    """
    r = np.asarray(range_m, dtype=np.float64)
    return np.interp(r, table[:, 0], table[:, 1], right=0.0).astype(np.float32)
