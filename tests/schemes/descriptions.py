"""Hand-made body and culture descriptions for the scheme tests (no endpoint, no bus)."""

from __future__ import annotations

import numpy as np

from hub.protocol import Description
from hub.schemes import SchemeContext

PAPER7_DEG = [-90.0, -60.0, -30.0, 0.0, 30.0, 60.0, 90.0]


def body(
    angles_deg=PAPER7_DEG, *, max_range_m=0.25, wheel_base_m=0.053, max_wheel_mps=0.2
) -> Description:
    """A body with range finders at ``angles_deg`` (CCW from forward)."""
    return Description(
        role="body",
        id="0",
        kind="test_body",
        sensor_angles_rad=np.deg2rad(np.asarray(angles_deg, dtype=np.float64)),
        max_range_m=max_range_m,
        wheel_base_m=wheel_base_m,
        radius_m=0.035,
        max_wheel_mps=max_wheel_mps,
    )


def grid(n: int = 32, spacing_um: float = 50.0, *, inhibitory_every: int = 0) -> Description:
    """An n × n culture like sim_network's: channel i at column i % n, row i // n.

    With ``inhibitory_every = k`` every k-th channel is inhibitory (cell_type 1).
    """
    i = np.arange(n * n)
    cell_type = None
    if inhibitory_every:
        cell_type = (i % inhibitory_every == inhibitory_every - 1).astype(np.uint8)
    return Description(
        role="culture",
        id="0",
        kind="test_culture",
        channel=i,
        x_um=(i % n + 0.5) * spacing_um,
        y_um=(i // n + 0.5) * spacing_um,
        cell_type=cell_type,
    )


def points(xy_um, channels=None) -> Description:
    """A culture of channels at the given (x, y) positions (µm)."""
    xy = np.asarray(xy_um, dtype=np.float64)
    ch = np.arange(len(xy)) if channels is None else np.asarray(channels)
    return Description(
        role="culture", id="0", kind="test_culture", channel=ch, x_um=xy[:, 0], y_um=xy[:, 1]
    )


def context(section: str = "coding", body_desc=None, culture_desc=None, **params):
    """A SchemeContext with a 10 ms period and the given parameters."""
    return SchemeContext(
        body=body() if body_desc is None else body_desc,
        culture=grid() if culture_desc is None else culture_desc,
        params=params,
        period_ms=10.0,
        section=section,
    )
