"""Virtual multi-electrode array: electrodes that record and stimulate nearby neurons.

Default: the Multi Channel Systems 60-electrode layout (``devices.mea``: 8 × 8 grid without
its corners, 200 µm pitch), centred on the culture. An electrode records every spike of each
neuron within `record_radius_um` (a neuron near two electrodes appears on both) and a pulse on
an electrode is delivered, at full amplitude, to every neuron within `stim_radius_um`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from devices.mea import positions
from sim_network.config import MeaConfig
from sim_network.layout import Layout


@dataclass(frozen=True)
class Mea:
    """Electrode positions and the two neuron↔electrode maps in CSR form.

    Attributes
    ----------
    x_um, y_um : float32[e]
        Electrode positions (µm).
    rec_indptr, rec_electrode : int64[n + 1], uint32
        Electrodes that record neuron i: ``rec_electrode[rec_indptr[i]:rec_indptr[i + 1]]``.
    stim_indptr, stim_neuron : int64[e + 1], int64
        Neurons that electrode j stimulates: ``stim_neuron[stim_indptr[j]:stim_indptr[j + 1]]``.
    """

    x_um: np.ndarray  # float32[e]
    y_um: np.ndarray  # float32[e]
    rec_indptr: np.ndarray  # int64[n + 1]: electrodes recording neuron i
    rec_electrode: np.ndarray  # uint32
    stim_indptr: np.ndarray  # int64[e + 1]: neurons stimulated by electrode j
    stim_neuron: np.ndarray  # int64

    @property
    def n_electrodes(self) -> int:
        """Number of electrodes."""
        return int(self.x_um.size)


def electrode_positions(cfg: MeaConfig, centre_x_um: float, centre_y_um: float):
    """Electrode positions of the configured grid, centred on a point.

    Parameters
    ----------
    cfg : MeaConfig
        Grid size, pitch and whether the corners are left out.
    centre_x_um, centre_y_um : float
        Centre of the grid (µm).

    Returns
    -------
    x_um, y_um : float32[e]
        Electrode positions, row-major (``devices.mea.grid``): with the default config, the
        electrodes in the order of ``devices.mea.MCS60_NAMES``.
    """
    return positions(cfg.rows, cfg.cols, cfg.pitch_um, cfg.drop_corners, (centre_x_um, centre_y_um))


def _csr(owner: np.ndarray, member: np.ndarray, n_owner: int):
    order = np.argsort(owner, kind="stable")
    indptr = np.zeros(n_owner + 1, dtype=np.int64)
    np.cumsum(np.bincount(owner, minlength=n_owner), out=indptr[1:])
    return indptr, member[order]


def build_mea(cfg: MeaConfig, layout: Layout) -> Mea:
    """Place the electrodes on the culture's centre and map the neurons within their radii.

    Parameters
    ----------
    cfg : MeaConfig
        Grid, pitch, recording and stimulation radii.
    layout : Layout
        The neurons.

    Returns
    -------
    Mea
        Electrodes in the order of `electrode_positions`.
    """
    ex, ey = electrode_positions(cfg, layout.width_um / 2.0, layout.height_um / 2.0)
    dx = layout.x_um[:, None].astype(np.float64) - ex[None, :]
    dy = layout.y_um[:, None].astype(np.float64) - ey[None, :]
    dist = np.hypot(dx, dy)  # n × e; e is small (60), so this stays cheap
    neuron, electrode = np.nonzero(dist <= cfg.record_radius_um)
    rec_indptr, rec_electrode = _csr(neuron, electrode.astype(np.uint32), layout.n)
    neuron, electrode = np.nonzero(dist <= cfg.stim_radius_um)
    stim_indptr, stim_neuron = _csr(electrode, neuron.astype(np.int64), ex.size)
    return Mea(ex, ey, rec_indptr, rec_electrode, stim_indptr, stim_neuron)
