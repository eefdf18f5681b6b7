"""A Khepera's IR proximity values as distances, and its wheel odometry as a pose.

Both are pure: :class:`IRCalibration` inverts a (distance, value) table, :class:`Odometry`
integrates position-counter changes along arcs.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from devices import khepera
from hub.config import ConfigError


class IRCalibration:
    """Proximity values (0–1023, higher = nearer) → distances (m), by a calibration table.

    Parameters
    ----------
    table : array of (distance_m, value)
        Measured points; distances increasing, values decreasing with distance.

    A value above the table's largest reads as its nearest distance; one below its smallest
    (the noise floor) as ``max_range_m``, the farthest distance in the table: "nothing seen".
    """

    def __init__(self, table: np.ndarray):
        table = np.asarray(table, dtype=np.float64)
        if table.ndim != 2 or table.shape[1] != 2 or len(table) < 2:
            raise ValueError("an IR table has two columns, distance_m and value, and 2+ rows")
        if not np.isfinite(table).all():
            raise ValueError("an IR table's distances and values must be numbers (not NaN or inf)")
        if (table[:, 0] < 0).any():
            raise ValueError("an IR table's distances must be >= 0 m")
        table = table[np.argsort(table[:, 0], kind="stable")]
        # Keep one distance per value: the nearest distance of a saturated value (1023).
        values, first = np.unique(table[:, 1], return_index=True)
        distances = table[first, 0]
        order = np.argsort(values)
        if np.any(np.diff(distances[order]) > 0):
            raise ValueError("IR values must decrease as distance increases")
        self.table = table
        self._values, self._distances = values[order], distances[order]
        self.max_range_m = float(table[:, 0].max())

    @classmethod
    def published(cls) -> IRCalibration:
        """The published Khepera II table (``devices.khepera.KHEPERA2_IR_TABLE``)."""
        return cls(khepera.MODELS["khepera2"].ir_table)

    @classmethod
    def from_file(cls, path: str | Path, key: str = "body.params.ir_table_file") -> IRCalibration:
        """A lab's own table: a CSV file with the header ``distance_m,value``.

        Parameters
        ----------
        path : path
            The CSV file: the header, then one ``distance_m,value`` row per measured point.
        key : str
            The setting that named the file, for the message.

        Raises
        ------
        ConfigError
            Naming ``key``: the file is missing or not a valid table.
        """
        try:
            with open(path) as f:
                header = f.readline().strip().replace(" ", "")
                if header != "distance_m,value":
                    raise ValueError(f"first line must be 'distance_m,value', got {header!r}")
                table = np.loadtxt(f, delimiter=",", ndmin=2)
            return cls(table)
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{key}: {path}: {exc}") from None

    def range_m(self, values: np.ndarray) -> np.ndarray:
        """Distances (m, float32) for proximity values (any shape)."""
        v = np.asarray(values, dtype=np.float64)
        out = np.interp(v, self._values, self._distances)
        out[v < self._values[0]] = self.max_range_m
        return out.astype(np.float32)


class Odometry:
    """The pose from the wheels' position counters (encoder pulses), along exact arcs.

    Parameters
    ----------
    pulse_m : float
        Distance per encoder pulse.
    wheel_base_m : float
        Distance between the wheels.
    """

    def __init__(self, pulse_m: float, wheel_base_m: float):
        self.pulse_m, self.wheel_base_m = pulse_m, wheel_base_m
        self.pose = np.zeros(3)
        self._last: tuple[int, int] | None = None

    def reset(self, pose, counters: tuple[int, int] | None = None) -> None:
        """Start again at ``pose``, with the position counters as they read now.

        Parameters
        ----------
        pose : (x_m, y_m, heading_rad)
            Where the robot is.
        counters : (int, int), optional
            The wheels' counters (pulses) at ``pose``; None: the next :meth:`update`'s
            counters are taken as the start, and it does not move the pose.
        """
        self.pose = np.asarray(pose, dtype=np.float64).copy()
        self._last = counters

    def update(self, counters: tuple[int, int]) -> np.ndarray:
        """Move by the counters' change since the last update; return the pose."""
        if self._last is None:
            self._last = counters
            return self.pose.copy()
        d_left = (counters[0] - self._last[0]) * self.pulse_m
        d_right = (counters[1] - self._last[1]) * self.pulse_m
        self._last = counters
        x, y, th = self.pose
        d = 0.5 * (d_left + d_right)
        d_th = (d_right - d_left) / self.wheel_base_m
        if abs(d_th) < 1e-12:
            x, y = x + d * math.cos(th), y + d * math.sin(th)
        else:
            r = d / d_th
            x += r * (math.sin(th + d_th) - math.sin(th))
            y -= r * (math.cos(th + d_th) - math.cos(th))
        th = (th + d_th + math.pi) % (2 * math.pi) - math.pi
        self.pose = np.array([x, y, th])
        return self.pose.copy()
