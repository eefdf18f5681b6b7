"""Single-channel burst detection (paper: at least 3 spikes within 20 ms).

Definition used here (and, identically, by the online detector in ``online.py``):

1. A spike is a *core* spike when it belongs to some run of ``min_spikes`` consecutive spikes of
   its channel whose span (last minus first time) is ``<= window_ms``.
2. A *burst* is a maximal run of consecutive spikes of one channel that are all core spikes and
   whose successive intervals are all ``<= max_isi_ms`` (default: ``window_ms``). A non-core spike,
   or a longer interval, ends the burst.
3. Runs shorter than ``min_spikes`` (possible only when ``max_isi_ms < window_ms``) are dropped.

A burst's ``start_ms`` and ``end_ms`` are the times of its first and last spike.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hub.analysis.spikes import AnalysisInputError, check_spikes

BURST_DTYPE = np.dtype(
    [
        ("channel", np.uint32),
        ("start_ms", np.float64),
        ("end_ms", np.float64),
        ("n_spikes", np.uint32),
    ]
)


@dataclass(frozen=True)
class BurstParams:
    """Thresholds of the burst definition (defaults: the paper's 3 spikes within 20 ms).

    Attributes
    ----------
    min_spikes : int
        Spikes (>= 2) that must fall within ``window_ms`` on one channel to start a burst.
    window_ms : float
        That window (> 0).
    max_isi_ms : float or None
        The interval above which a burst ends; None: ``window_ms``.
    """

    min_spikes: int = 3
    window_ms: float = 20.0
    max_isi_ms: float | None = None

    def __post_init__(self):
        if int(self.min_spikes) != self.min_spikes or self.min_spikes < 2:
            raise AnalysisInputError(
                f"bursts.min_spikes must be an integer >= 2, got {self.min_spikes}"
            )
        if not self.window_ms > 0:
            raise AnalysisInputError(f"bursts.window_ms must be > 0, got {self.window_ms}")
        if self.max_isi_ms is not None and not self.max_isi_ms > 0:
            raise AnalysisInputError(f"bursts.max_isi_ms must be > 0, got {self.max_isi_ms}")

    @property
    def isi_limit_ms(self) -> float:
        """The interval above which a burst ends (``max_isi_ms`` or else ``window_ms``)."""
        return float(self.window_ms if self.max_isi_ms is None else self.max_isi_ms)


def empty_bursts() -> np.ndarray:
    """No bursts.

    Returns
    -------
    BURST_DTYPE array
        Of length 0.
    """
    return np.zeros(0, dtype=BURST_DTYPE)


def detect_bursts(channel, t_ms, params: BurstParams | None = None) -> np.ndarray:
    """Detect bursts on every channel.

    Vectorised: one sort plus a few passes over the spikes.

    Parameters
    ----------
    channel : int array[k]
        Channel of each spike.
    t_ms : float array[k]
        Time of each spike (ms); any order.
    params : BurstParams, optional
        Default the paper's.

    Returns
    -------
    BURST_DTYPE array
        (channel, start_ms, end_ms, n_spikes) of each burst, sorted by ``start_ms`` then
        ``channel``.
    """
    p = params or BurstParams()
    ch, t = check_spikes(channel, t_ms)
    m = int(p.min_spikes)
    n = t.size
    if n < m:
        return empty_bursts()
    order = np.lexsort((t, ch))
    ch, t = ch[order], t[order]

    # 1. core spikes: every run of m consecutive same-channel spikes spanning <= window_ms.
    run_ok = (ch[m - 1 :] == ch[: n - m + 1]) & (t[m - 1 :] - t[: n - m + 1] <= p.window_ms)
    first = np.flatnonzero(run_ok)
    cover = np.zeros(n + 1, dtype=np.int64)
    cover[first] += 1
    cover[first + m] -= 1
    core = np.cumsum(cover[:n]) > 0

    # 2. group consecutive core spikes of one channel with intervals <= the ISI limit.
    cont = np.zeros(n, dtype=bool)
    cont[1:] = core[1:] & core[:-1] & (ch[1:] == ch[:-1]) & (np.diff(t) <= p.isi_limit_ms)
    starts = np.flatnonzero(core & ~cont)
    is_end = core.copy()
    is_end[:-1] &= ~cont[1:]
    ends = np.flatnonzero(is_end)
    n_spikes = ends - starts + 1

    # 3. drop runs shorter than min_spikes.
    keep = n_spikes >= m
    starts, ends, n_spikes = starts[keep], ends[keep], n_spikes[keep]
    out = np.empty(starts.size, dtype=BURST_DTYPE)
    out["channel"] = ch[starts]
    out["start_ms"] = t[starts]
    out["end_ms"] = t[ends]
    out["n_spikes"] = n_spikes
    return sort_bursts(out)


def sort_bursts(bursts: np.ndarray) -> np.ndarray:
    """Bursts in the order every function here returns them.

    Parameters
    ----------
    bursts : BURST_DTYPE array

    Returns
    -------
    BURST_DTYPE array
        Sorted by start time, then channel.
    """
    return bursts[np.lexsort((bursts["channel"], bursts["start_ms"]))]


def bursting_rate_per_min(bursts: np.ndarray, n_channels: int, duration_ms: float) -> np.ndarray:
    """Bursts per minute of every channel (MBR is its mean).

    Parameters
    ----------
    bursts : BURST_DTYPE array
    n_channels : int
        Channels recorded (those without bursts count as 0).
    duration_ms : float
        The recorded span (> 0).

    Returns
    -------
    float64[n_channels]
    """
    if duration_ms <= 0:
        raise AnalysisInputError(f"duration_ms must be > 0, got {duration_ms}")
    counts = np.bincount(bursts["channel"].astype(np.int64), minlength=n_channels)
    return counts / (duration_ms / 60_000.0)
