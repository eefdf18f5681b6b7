"""Which instrument channel is which electrode, and where each electrode sits (µm).

The default is the Multi Channel Systems 60-electrode layout (``devices.mea``: 8 × 8 without
the corners, 200 µm pitch) wired in electrode order to Intan channels ``a-000``…``a-031``
then ``b-000``…``b-027``. A lab's own wiring is a CSV file ``name,x_um,y_um`` (one line per
electrode, the instrument's channel name first).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from devices import mea
from hub.config import ConfigError


@dataclass(frozen=True)
class ElectrodeLayout:
    """Electrodes: channel id on the wire (0..n-1), instrument name, position (µm)."""

    names: tuple[str, ...]
    x_um: np.ndarray
    y_um: np.ndarray

    def __post_init__(self):
        if len(set(self.names)) != len(self.names):
            raise ValueError("electrode names must be unique")
        if not (len(self.names) == self.x_um.size == self.y_um.size):
            raise ValueError("one position per electrode")

    @property
    def n(self) -> int:
        """How many electrodes."""
        return len(self.names)

    @property
    def channel(self) -> np.ndarray:
        """The channel ids on the wire, ``0..n-1`` (uint32)."""
        return np.arange(self.n, dtype=np.uint32)

    def index(self) -> dict[str, int]:
        """Instrument name → channel id."""
        return {name: i for i, name in enumerate(self.names)}

    @classmethod
    def mcs60(cls, pitch_um: float = mea.MCS60_PITCH_UM) -> ElectrodeLayout:
        """The MCS 60-electrode layout on Intan ports A and B, centred at (0, 0)."""
        x, y = mea.positions(mea.MCS60_ROWS, mea.MCS60_COLS, pitch_um, drop_corners=True)
        names = tuple(f"a-{i:03d}" if i < 32 else f"b-{i - 32:03d}" for i in range(x.size))
        return cls(names, x, y)

    @classmethod
    def from_file(cls, path: str | Path, key: str = "culture.params.layout_file"):
        """A CSV ``name,x_um,y_um`` with that header.

        Parameters
        ----------
        path : path
            The file: the header, then one row per electrode in channel order (the
            instrument's channel name, its position in µm); blank lines are skipped. Names
            are taken in lower case, as the driver matches the instrument's (``A-010`` is
            ``a-010``).
        key : str
            The setting that named the file, for the message.

        Raises
        ------
        ConfigError
            Naming ``key``: missing file, bad header, a bad row, duplicate names.
        """
        try:
            lines = Path(path).read_text().splitlines()
            if not lines or lines[0].replace(" ", "") != "name,x_um,y_um":
                raise ValueError("first line must be 'name,x_um,y_um'")
            names, xs, ys = [], [], []
            for n, line in enumerate(lines[1:], start=2):
                if not line.strip():
                    continue
                parts = [p.strip() for p in line.split(",")]
                if len(parts) != 3:
                    raise ValueError(f"line {n}: expected name,x_um,y_um")
                names.append(parts[0].lower())  # the instrument's names ignore case
                xs.append(float(parts[1]))
                ys.append(float(parts[2]))
            return cls(tuple(names), np.array(xs, np.float32), np.array(ys, np.float32))
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{key}: {path}: {exc}") from None
