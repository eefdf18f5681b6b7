"""Robot bodies: a differential-drive disc carrying range finders, and the ready presets.

Body frame: x forward, y to the left; sensor angles are counter-clockwise from forward, in
the order the sensors are listed (that order is the order of ``read_sensors()``).

Presets (``PRESETS``):

* ``khepera2`` — the real robot's disc, wheel base, 8 IR sensors at their positions and
  facings and max wheel speed (``devices.khepera``: 70 mm, 53 mm, 1.016 m/s), range finders
  capped at the IR fade distance (0.12 m) with the Khepera II IR response.
* ``khepera3`` — the real robot's 9 IR sensors around the body at their positions and
  facings, its disc, wheel base and regulated top speed (``devices.khepera``: 128 mm, 88.5 mm,
  0.299 m/s), range finders to the IR's 0.2 m; no IR response model (none is published: a
  lab's table maps ranges to values, as the emulator does).
* ``khepera4`` — the real robot's radius, wheel base and 8 IR facings (``devices.khepera``:
  70.4 mm, 105.4 mm, evenly spaced on the rim); max range 0.25 m and max wheel speed 0.81 m/s
  are our assumptions (not in the reference notes).
* ``paper7`` — the paper's Figure 7 robot: a Khepera II-sized disc with 7 range finders on the
  rim at -90°..+90° every 30° (right to left), max range 0.25 m, wheels capped at 0.2 m/s.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass

import numpy as np

from devices import khepera

from .errors import WorldError
from .ir import IR_FADE_M, IR_MODELS


@dataclass(frozen=True, eq=False)
class Body:
    """A differential-drive robot with range finders.

    Attributes
    ----------
    name : str
        Preset or user name.
    radius_m : float
        Radius of the body's disc (collisions, contact).
    wheel_base_m : float
        Distance between the wheels.
    max_wheel_mps : float
        Wheel speeds saturate at ``±max_wheel_mps``.
    sensor_angles_rad : float32[n_sensors]
        Facing of each range finder, counter-clockwise from forward.
    sensor_offsets_m : float64[n_sensors, 2]
        Position of each range finder in the body frame (x forward, y left).
    max_range_m : float
        Range reported when nothing is hit.
    ir_model : str or None
        Name of an IR response (``sim_robot.ir.IR_MODELS``) for ``Arena.read_ir``, or None.
    """

    name: str
    radius_m: float
    wheel_base_m: float
    max_wheel_mps: float
    sensor_angles_rad: np.ndarray
    sensor_offsets_m: np.ndarray
    max_range_m: float
    ir_model: str | None = None

    @property
    def n_sensors(self) -> int:
        """Number of range sensors (one per entry of ``sensor_angles_rad``)."""
        return int(self.sensor_angles_rad.shape[0])

    def __post_init__(self) -> None:
        angles = np.asarray(self.sensor_angles_rad, dtype=np.float32).reshape(-1)
        offsets = np.asarray(self.sensor_offsets_m, dtype=np.float64)
        object.__setattr__(self, "sensor_angles_rad", angles)
        object.__setattr__(self, "sensor_offsets_m", offsets)
        for key in ("radius_m", "wheel_base_m", "max_wheel_mps", "max_range_m"):
            value = getattr(self, key)
            ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
            if not (ok and math.isfinite(value) and value > 0):
                raise WorldError(f"robot.{key} must be a finite number > 0, got {value!r}")
        if angles.size == 0:
            raise WorldError("robot.sensor_angles_deg must list at least one sensor, got none")
        if not np.all(np.isfinite(angles)):
            raise WorldError("robot.sensor_angles_deg must be finite numbers")
        if offsets.shape != (angles.size, 2) or not np.all(np.isfinite(offsets)):
            raise WorldError(
                f"robot.sensor_offsets_m must be {angles.size} finite [x, y] pairs "
                f"(one per sensor), got shape {offsets.shape}"
            )
        if self.ir_model is not None and self.ir_model not in IR_MODELS:
            raise WorldError(
                f"robot.ir_model must be one of {sorted(IR_MODELS)} or 'none', "
                f"got {self.ir_model!r}"
            )

    def replace(self, **changes) -> Body:
        """A copy with some fields changed.

        Parameters
        ----------
        **changes
            Field values, by name.

        Returns
        -------
        Body
            Validated again.
        """
        return dataclasses.replace(self, **changes)


def rim_offsets(radius_m: float, angles_rad: np.ndarray) -> np.ndarray:
    """Sensor positions on the rim of a disc, each facing outward along its angle.

    Parameters
    ----------
    radius_m : float
        The disc.
    angles_rad : float array[k]
        Facing of each sensor, counter-clockwise from forward.

    Returns
    -------
    float64[k, 2]
        (x, y) of each sensor in the body frame (m).
    """
    a = np.asarray(angles_rad, dtype=np.float64)
    return np.stack([radius_m * np.cos(a), radius_m * np.sin(a)], axis=1)


def custom_body(
    sensor_angles_deg,
    max_range_m: float,
    radius_m: float = khepera.KHEPERA2_RADIUS_M,
    wheel_base_m: float = khepera.KHEPERA2_WHEEL_BASE_M,
    max_wheel_mps: float = 0.2,
    sensor_offsets_m=None,
    ir_model: str | None = None,
    name: str = "custom",
) -> Body:
    """A body with range finders at user-chosen directions.

    Parameters
    ----------
    sensor_angles_deg : array_like of float
        Facing of each range finder (deg, counter-clockwise from forward).
    max_range_m : float
        Range reported when nothing is hit.
    radius_m, wheel_base_m : float
        The disc and the distance between the wheels (default a Khepera II's,
        ``devices.khepera``).
    max_wheel_mps : float
        Wheel speed limit.
    sensor_offsets_m : array_like, shape (k, 2), optional
        Sensor positions in the body frame; default on the rim (`rim_offsets`).
    ir_model : str, optional
        A key of ``sim_robot.ir.IR_MODELS`` for ``Arena.read_ir``.
    name : str
        Shown in messages.

    Returns
    -------
    Body
        Validated (`WorldError` names a bad field).
    """
    angles = np.deg2rad(np.asarray(sensor_angles_deg, dtype=np.float64).reshape(-1))
    offsets = rim_offsets(radius_m, angles) if sensor_offsets_m is None else sensor_offsets_m
    return Body(
        name=name,
        radius_m=float(radius_m),
        wheel_base_m=float(wheel_base_m),
        max_wheel_mps=float(max_wheel_mps),
        sensor_angles_rad=angles,
        sensor_offsets_m=np.asarray(offsets, dtype=np.float64),
        max_range_m=float(max_range_m),
        ir_model=ir_model,
    )


def _khepera2() -> Body:
    return custom_body(
        khepera.KHEPERA2_SENSOR_FACINGS_DEG,
        max_range_m=IR_FADE_M,
        radius_m=khepera.KHEPERA2_RADIUS_M,
        wheel_base_m=khepera.KHEPERA2_WHEEL_BASE_M,
        max_wheel_mps=khepera.KHEPERA2_MAX_WHEEL_MPS,
        sensor_offsets_m=khepera.KHEPERA2_SENSOR_POSITIONS_M,
        ir_model="khepera2",
        name="khepera2",
    )


def _khepera3() -> Body:
    return custom_body(
        khepera.KHEPERA3_SENSOR_FACINGS_DEG,
        max_range_m=khepera.KHEPERA3_IR_RANGE_M[1],
        radius_m=khepera.KHEPERA3_RADIUS_M,
        wheel_base_m=khepera.KHEPERA3_WHEEL_BASE_M,
        max_wheel_mps=khepera.MODELS["khepera3"].max_wheel_mps,
        sensor_offsets_m=khepera.KHEPERA3_SENSOR_POSITIONS_M,
        name="khepera3",
    )


def _khepera4() -> Body:
    return custom_body(
        khepera.KHEPERA4_SENSOR_FACINGS_DEG,
        max_range_m=0.25,
        radius_m=khepera.KHEPERA4_RADIUS_M,
        wheel_base_m=khepera.KHEPERA4_WHEEL_BASE_M,
        max_wheel_mps=0.81,
        name="khepera4",
    )


def _paper7() -> Body:
    return custom_body(np.arange(-90.0, 91.0, 30.0), max_range_m=0.25, name="paper7")


PRESETS = {
    "khepera2": _khepera2,
    "khepera3": _khepera3,
    "khepera4": _khepera4,
    "paper7": _paper7,
}


def preset(name: str) -> Body:
    """A ready body by name.

    Parameters
    ----------
    name : str
        One of ``PRESETS``: ``"khepera2"``, ``"khepera4"``, ``"paper7"``.

    Returns
    -------
    Body
        A new body.

    Raises
    ------
    WorldError
        For an unknown name.
    """
    try:
        return PRESETS[name]()
    except KeyError:
        raise WorldError(f"robot.preset must be one of {sorted(PRESETS)}, got {name!r}") from None
