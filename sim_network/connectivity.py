"""Distance-dependent random connectivity in CSR form, built without O(N²) loops.

For each ordered pair at distance d ≤ cutoff: P = p_c_max · exp(-d / d_pc_um). Because the
neurons sit on a grid, the candidate partners of every neuron are the same set of grid
offsets; the builder loops over offsets (not pairs) and draws all pres of one offset at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim_network.config import ConnectivityConfig
from sim_network.layout import EXCITATORY, Layout

UM_PER_MS_PER_M_S = 1000.0  # 1 m/s = 1000 µm/ms


@dataclass
class Synapses:
    """Synapses sorted by presynaptic neuron (CSR): those of neuron i are indptr[i]:indptr[i+1].

    Attributes
    ----------
    indptr : int64[n + 1]
        Row pointers.
    post : int32[m]
        Postsynaptic neuron of each synapse.
    weight_mv : float64[m]
        Jump of the postsynaptic potential on arrival (mV; negative for inhibitory).
    delay_ms : float32[m]
        Synaptic delay + distance / conduction speed.
    distance_um : float32[m]
        Distance between the two neurons.
    """

    indptr: np.ndarray  # int64[n + 1]
    post: np.ndarray  # int32[m]
    weight_mv: np.ndarray  # float64[m], jump of the postsynaptic potential on arrival
    delay_ms: np.ndarray  # float32[m], synaptic delay + distance / speed
    distance_um: np.ndarray  # float32[m]

    @property
    def n_synapses(self) -> int:
        """Number of synapses."""
        return int(self.post.size)

    def permuted(self, order: np.ndarray) -> Synapses:
        """The same synapses in another order within each row.

        Parameters
        ----------
        order : int64[m]
            A permutation that keeps every synapse in its row (e.g. from
            `kernels.row_order`).

        Returns
        -------
        Synapses
            With ``indptr`` unchanged and every other array reordered.
        """
        return Synapses(
            indptr=self.indptr,
            post=self.post[order],
            weight_mv=self.weight_mv[order],
            delay_ms=self.delay_ms[order],
            distance_um=self.distance_um[order],
        )

    def pre(self) -> np.ndarray:
        """The presynaptic neuron of every synapse.

        Returns
        -------
        int32[m]
            Row index of each synapse.
        """
        counts = np.diff(self.indptr)
        return np.repeat(np.arange(counts.size, dtype=np.int32), counts)


def connection_probability(distance_um: np.ndarray, cfg: ConnectivityConfig) -> np.ndarray:
    """The probability that a neuron connects to another at a distance: the builder's rule.

    Parameters
    ----------
    distance_um : array_like
        Distances between the two neurons (µm).
    cfg : ConnectivityConfig
        ``p_c_max``, ``d_pc_um`` and ``cutoff_um``.

    Returns
    -------
    float64 array
        ``p_c_max · exp(-d / d_pc_um)`` for ``d <= cutoff_um``, else 0.
    """
    d = np.asarray(distance_um, dtype=np.float64)
    p = cfg.p_c_max * np.exp(-d / cfg.d_pc_um)
    return np.where(d <= cfg.cutoff_um, p, 0.0)


def _offsets(layout: Layout, cfg: ConnectivityConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    reach_r = min(layout.rows - 1, int(cfg.cutoff_um // layout.spacing_um))
    reach_c = min(layout.cols - 1, int(cfg.cutoff_um // layout.spacing_um))
    dr, dc = np.meshgrid(
        np.arange(-reach_r, reach_r + 1), np.arange(-reach_c, reach_c + 1), indexing="ij"
    )
    dr = dr.ravel()
    dc = dc.ravel()
    dist = np.hypot(dr, dc) * layout.spacing_um
    keep = dist <= cfg.cutoff_um
    if not cfg.allow_self:
        keep &= (dr != 0) | (dc != 0)
    return dr[keep], dc[keep], dist[keep]


def build_synapses(layout: Layout, cfg: ConnectivityConfig, rng: np.random.Generator) -> Synapses:
    """Draw the culture's synapses.

    Every ordered pair of neurons connects with :func:`connection_probability` of its
    distance (no self-connections unless ``cfg.allow_self``); weights are uniform in the
    range of the presynaptic neuron's type, conduction speeds uniform in ``speed_m_s``.

    Parameters
    ----------
    layout : Layout
        Grid positions and cell types.
    cfg : ConnectivityConfig
        The rule, weights, delays and speeds.
    rng : numpy.random.Generator
        The source of every draw (the same generator state gives the same synapses).

    Returns
    -------
    Synapses
        In CSR form by presynaptic neuron, with weights (mV), delays (synaptic delay plus
        distance / speed, ms) and distances (µm).
    """
    rows, cols = layout.rows, layout.cols
    pres: list[np.ndarray] = []
    posts: list[np.ndarray] = []
    dists: list[np.ndarray] = []
    for dr, dc, d in zip(*_offsets(layout, cfg), strict=True):
        p = connection_probability(d, cfg)
        if p <= 0.0:
            continue
        r = np.arange(max(0, -dr), rows - max(0, dr))
        c = np.arange(max(0, -dc), cols - max(0, dc))
        pre = (r[:, None] * cols + c[None, :]).ravel()
        hit = pre[rng.random(pre.size) < p]
        if hit.size:
            pres.append(hit)
            posts.append(hit + (dr * cols + dc))
            dists.append(np.full(hit.size, d, dtype=np.float32))
    if pres:
        pre = np.concatenate(pres)
        post = np.concatenate(posts)
        dist = np.concatenate(dists)
        order = np.argsort(pre, kind="stable")
        pre, post, dist = pre[order], post[order].astype(np.int32), dist[order]
    else:
        pre = np.zeros(0, dtype=np.int64)
        post = np.zeros(0, dtype=np.int32)
        dist = np.zeros(0, dtype=np.float32)
    indptr = np.zeros(layout.n + 1, dtype=np.int64)
    np.cumsum(np.bincount(pre, minlength=layout.n), out=indptr[1:])
    m = pre.size
    exc = layout.cell_type[pre] == EXCITATORY
    lo = np.where(exc, cfg.weight_exc_mv[0], cfg.weight_inh_mv[0])
    hi = np.where(exc, cfg.weight_exc_mv[1], cfg.weight_inh_mv[1])
    weight = lo + (hi - lo) * rng.random(m)
    speed = cfg.speed_m_s[0] + (cfg.speed_m_s[1] - cfg.speed_m_s[0]) * rng.random(m)
    delay = cfg.synaptic_delay_ms + dist / (speed * UM_PER_MS_PER_M_S)
    return Synapses(
        indptr=indptr,
        post=post,
        weight_mv=weight.astype(np.float64),
        delay_ms=delay.astype(np.float32),
        distance_um=dist,
    )


def delay_steps(delay_ms: np.ndarray, dt_ms: float) -> np.ndarray:
    """Delays in whole steps.

    Parameters
    ----------
    delay_ms : float array
        Delays (ms).
    dt_ms : float
        The step.

    Returns
    -------
    int32 array
        round(delay / dt), at least 1 (a spike never arrives in the step it was fired).
    """
    return np.maximum(1, np.rint(delay_ms / dt_ms)).astype(np.int32)
