"""Population layout: neurons at the centres of the cells of a square grid, E/I at random."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from devices.culture import EXCITATORY, INHIBITORY
from sim_network.config import LayoutConfig

__all__ = ["EXCITATORY", "INHIBITORY", "Layout", "build_layout"]


@dataclass(frozen=True)
class Layout:
    """Grid positions and cell types; neuron index = row · cols + col.

    Attributes
    ----------
    rows, cols : int
        Grid size.
    spacing_um : float
        Distance between neighbouring neurons (µm).
    row, col : int32[n]
        Grid cell of each neuron.
    x_um, y_um : float32[n]
        Position (µm) of each neuron: the centre of its cell.
    cell_type : uint8[n]
        `EXCITATORY` (0) or `INHIBITORY` (1).
    """

    rows: int
    cols: int
    spacing_um: float
    row: np.ndarray  # int32[n]
    col: np.ndarray  # int32[n]
    x_um: np.ndarray  # float32[n], cell centre
    y_um: np.ndarray  # float32[n]
    cell_type: np.ndarray  # uint8[n], 0 excitatory, 1 inhibitory

    @property
    def n(self) -> int:
        """Number of neurons."""
        return self.rows * self.cols

    @property
    def width_um(self) -> float:
        """Culture extent along x."""
        return self.cols * self.spacing_um

    @property
    def height_um(self) -> float:
        """Culture extent along y."""
        return self.rows * self.spacing_um


def build_layout(cfg: LayoutConfig, rng: np.random.Generator) -> Layout:
    """Place the neurons on the grid and choose which are inhibitory.

    Parameters
    ----------
    cfg : LayoutConfig
        Grid size, spacing and the inhibitory fraction.
    rng : numpy.random.Generator
        Chooses the inhibitory neurons.

    Returns
    -------
    Layout
        rows × cols neurons, exactly round(n · inhibitory_fraction) of them inhibitory.
    """
    n = cfg.rows * cfg.cols
    idx = np.arange(n)
    row = (idx // cfg.cols).astype(np.int32)
    col = (idx % cfg.cols).astype(np.int32)
    cell_type = np.zeros(n, dtype=np.uint8)
    n_inh = round(n * cfg.inhibitory_fraction)
    cell_type[rng.permutation(n)[:n_inh]] = INHIBITORY
    return Layout(
        rows=cfg.rows,
        cols=cfg.cols,
        spacing_um=cfg.spacing_um,
        row=row,
        col=col,
        x_um=((col + 0.5) * cfg.spacing_um).astype(np.float32),
        y_um=((row + 0.5) * cfg.spacing_um).astype(np.float32),
        cell_type=cell_type,
    )
