"""Network bursts: at least a fraction of all channels bursting at the same time (paper: 30 %).

Definition used here (and, identically, by the online detector in ``online.py``):

1. Each single-channel burst covers the closed interval ``[start_ms, end_ms]``. The bursting count
   ``B(t)`` is the number of bursts covering time ``t``.
2. A network-burst *segment* is a maximal interval where ``B(t) >= ceil(min_fraction *
   n_channels)`` (at least 1). Segments whose gap (next start minus previous end) is
   ``<= merge_gap_ms`` are merged into one network burst; the merged interval is its *core*
   (``core_start_ms``, ``core_end_ms``: the time the threshold is held).
3. A network burst's participating bursts are the single-channel bursts overlapping its core
   (closed intervals; so they include channels that burst during a merged gap), and its
   participating channels are their channels.
4. A network burst's ``start_ms`` / ``end_ms`` are its *extent*: the start of the earliest and
   the end of the latest participating burst, i.e. its first and last participating spike
   (the usual MEA reading of "network-burst duration"; the core is ~5x shorter). The extent
   always contains the core. Extents of consecutive network bursts may overlap when one
   long single-channel burst takes part in both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hub.analysis.bursts import BURST_DTYPE
from hub.analysis.spikes import AnalysisInputError


@dataclass(frozen=True)
class NetworkBurstParams:
    """Thresholds of the network-burst definition.

    Attributes
    ----------
    min_fraction : float
        Share of the channels, in (0, 1], that must burst at once.
    merge_gap_ms : float
        Segments above the threshold separated by at most this gap are one network burst.
    """

    min_fraction: float = 0.30
    merge_gap_ms: float = 10.0

    def __post_init__(self):
        if not 0.0 < self.min_fraction <= 1.0:
            raise AnalysisInputError(
                f"network_bursts.min_fraction must be in (0, 1], got {self.min_fraction}"
            )
        if not self.merge_gap_ms >= 0.0:
            raise AnalysisInputError(
                f"network_bursts.merge_gap_ms must be >= 0, got {self.merge_gap_ms}"
            )

    def min_channels(self, n_channels: int) -> int:
        """Number of simultaneously bursting channels that makes a network burst.

        Parameters
        ----------
        n_channels : int
            Channels recorded (>= 1).

        Returns
        -------
        int
            ceil(min_fraction · n_channels), at least 1.
        """
        if n_channels < 1:
            raise AnalysisInputError(f"n_channels must be >= 1, got {n_channels}")
        return max(1, math.ceil(self.min_fraction * n_channels - 1e-9))


@dataclass(frozen=True)
class NetworkBursts:
    """Network bursts of a record, sorted by core start.

    Attributes
    ----------
    start_ms, end_ms : float64[k]
        Extents: the earliest start and latest end of the participants' bursts.
    channels : list of uint32 arrays
        ``channels[i]``: the participants of network burst i.
    core_start_ms, core_end_ms : float64[k]
        The time at or above the threshold (see the module docstring); default the extent.
    """

    start_ms: np.ndarray
    end_ms: np.ndarray
    channels: list[np.ndarray] = field(default_factory=list)
    core_start_ms: np.ndarray | None = None
    core_end_ms: np.ndarray | None = None

    def __post_init__(self):
        if self.core_start_ms is None:
            object.__setattr__(self, "core_start_ms", np.asarray(self.start_ms).copy())
        if self.core_end_ms is None:
            object.__setattr__(self, "core_end_ms", np.asarray(self.end_ms).copy())

    def __len__(self) -> int:
        return int(self.start_ms.size)

    @property
    def duration_ms(self) -> np.ndarray:
        """Each network burst's extent, end minus start (ms)."""
        return self.end_ms - self.start_ms

    @property
    def core_duration_ms(self) -> np.ndarray:
        """Time spent at or above the threshold (merged gaps included)."""
        return self.core_end_ms - self.core_start_ms

    @property
    def n_channels(self) -> np.ndarray:
        """Number of participating channels of each network burst."""
        return np.array([c.size for c in self.channels], dtype=np.int64)

    def select(self, mask) -> NetworkBursts:
        """Some of the network bursts.

        Parameters
        ----------
        mask : bool array_like[len(self)]

        Returns
        -------
        NetworkBursts
            Those where ``mask`` is true, in order.
        """
        idx = np.flatnonzero(np.asarray(mask, dtype=bool))
        return NetworkBursts(
            self.start_ms[idx],
            self.end_ms[idx],
            [self.channels[i] for i in idx],
            self.core_start_ms[idx],
            self.core_end_ms[idx],
        )

    @classmethod
    def empty(cls) -> NetworkBursts:
        """No network bursts.

        Returns
        -------
        NetworkBursts
            Of length 0.
        """
        return cls(np.empty(0), np.empty(0), [], np.empty(0), np.empty(0))


def detect_network_bursts(
    bursts: np.ndarray, n_channels: int, params: NetworkBurstParams | None = None
) -> NetworkBursts:
    """Network bursts from single-channel bursts.

    Parameters
    ----------
    bursts : BURST_DTYPE array
        From `detect_bursts`; channels < ``n_channels``.
    n_channels : int
        Channels recorded (sets the threshold, `NetworkBurstParams.min_channels`).
    params : NetworkBurstParams, optional
        Default the paper's.

    Returns
    -------
    NetworkBursts
        Sorted by core start.
    """
    p = params or NetworkBurstParams()
    threshold = p.min_channels(n_channels)
    if bursts.dtype != BURST_DTYPE:
        raise AnalysisInputError(f"bursts must have dtype BURST_DTYPE, got {bursts.dtype}")
    if bursts.size == 0:
        return NetworkBursts.empty()
    if int(bursts["channel"].max()) >= n_channels:
        raise AnalysisInputError(
            f"bursts.channel must be < n_channels={n_channels}, got {bursts['channel'].max()}"
        )
    nb = bursts.size
    times = np.concatenate([bursts["start_ms"], bursts["end_ms"]])
    kind = np.concatenate([np.zeros(nb, np.int8), np.ones(nb, np.int8)])  # starts before ends
    order = np.lexsort((kind, times))
    times, kind = times[order], kind[order]
    count = np.cumsum(np.where(kind == 0, 1, -1))
    before = count - np.where(kind == 0, 1, -1)
    up = np.flatnonzero((kind == 0) & (count == threshold) & (before == threshold - 1))
    down = np.flatnonzero((kind == 1) & (count == threshold - 1) & (before == threshold))
    seg_start, seg_end = times[up], times[down]  # up/down alternate, starting with an up
    if seg_start.size == 0:
        return NetworkBursts.empty()
    # merge segments separated by a gap <= merge_gap_ms
    new = np.ones(seg_start.size, dtype=bool)
    new[1:] = seg_start[1:] - seg_end[:-1] > p.merge_gap_ms
    first = np.flatnonzero(new)
    last = np.append(first[1:] - 1, seg_start.size - 1)
    core_start, core_end = seg_start[first], seg_end[last]
    channels, start_ms, end_ms = _participants(bursts, core_start, core_end)
    return NetworkBursts(start_ms, end_ms, channels, core_start, core_end)


def _participants(bursts: np.ndarray, start_ms: np.ndarray, end_ms: np.ndarray):
    """Channels with a burst overlapping each ``[start_ms[i], end_ms[i]]``, and the earliest
    start and latest end of those bursts (the extent)."""
    order = np.argsort(bursts["start_ms"], kind="stable")
    b_start = bursts["start_ms"][order]
    b_end = bursts["end_ms"][order]
    b_ch = bursts["channel"][order]
    longest = float((b_end - b_start).max())
    lo = np.searchsorted(b_start, start_ms - longest, side="left")
    hi = np.searchsorted(b_start, end_ms, side="right")
    out = []
    ext_start = np.empty(start_ms.size)
    ext_end = np.empty(start_ms.size)
    for i in range(start_ms.size):
        sl = slice(lo[i], hi[i])
        hit = b_end[sl] >= start_ms[i]
        out.append(np.unique(b_ch[sl][hit]).astype(np.uint32))
        ext_start[i] = b_start[sl][hit].min()
        ext_end[i] = b_end[sl][hit].max()
    return out, ext_start, ext_end


def inter_burst_intervals_ms(network_bursts: NetworkBursts) -> np.ndarray:
    """IBI: intervals between the starts of consecutive network bursts' cores.

    The core's start (the threshold reached), not the extent's: a channel that bursts
    for seconds (one stimulated every step of a closed loop) takes part in every network
    burst it overlaps and pulls each one's extent back to its own start, where the cores
    keep their times. In spontaneous activity the two starts differ by a few ms.

    Parameters
    ----------
    network_bursts : NetworkBursts

    Returns
    -------
    float64[len - 1]
        Intervals between the cores' starts (ms).
    """
    return np.diff(network_bursts.core_start_ms)


def evoked_mask(
    network_bursts: NetworkBursts, stim_ms, max_latency_ms: float = 200.0
) -> np.ndarray:
    """Which network bursts a stimulus evoked.

    Parameters
    ----------
    network_bursts : NetworkBursts
    stim_ms : float array_like
        Stimulus times (ms), any order.
    max_latency_ms : float
        The longest latency of an evoked network burst.

    Returns
    -------
    bool[len(network_bursts)]
        True where the burst's core starts within ``[s, s + max_latency_ms]`` of the latest
        stimulus s before it. The core start (the moment the threshold is reached), not the
        extent's: a participant whose burst began a few ms before the pulse (a fast-spiking
        cell) puts the extent's start before the stimulus that evoked the network burst.
    """
    stim = np.sort(np.asarray(stim_ms, dtype=np.float64).ravel())
    if stim.size == 0 or len(network_bursts) == 0:
        return np.zeros(len(network_bursts), dtype=bool)
    start = network_bursts.core_start_ms
    idx = np.searchsorted(stim, start, side="right") - 1
    ok = idx >= 0
    latency = start - stim[np.maximum(idx, 0)]
    return ok & (latency <= max_latency_ms)
