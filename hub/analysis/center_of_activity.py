"""Center of Activity (CA) and its trajectories (CAT), after Chao et al. (2007) and the paper.

``CA(t, dt) = sum_n FR_n(t, dt) * [x_n, y_n] / sum_n FR_n(t, dt)`` with
``FR_n(t, dt) = (spikes of n in (t, t + dt]) / dt``: the spike-weighted mean position of the
channels firing in the window. Positions are the channels' ``x_um``, ``y_um`` (the paper's row and
column, in micrometres). A window with no spike has no CA (NaN).

A network burst's CAT links CAs over the burst: points are placed every ``step_ms`` on
``[start_ms, end_ms]`` and the point at time ``tc`` is ``CA(tc - time_scale_ms / 2,
time_scale_ms)``, i.e. the CA of a window of width ``time_scale_ms`` (the paper's "time scale",
50 ms by default) centred on ``tc``. Points whose window is empty are dropped.

CAT regularity (``cat_spread``): every CAT is resampled to ``n_points`` points, linearly in its
own normalised time (0 at its first point, 1 at its last); the distance between two CATs is the
mean Euclidean distance between corresponding points (µm); the spread is the mean of that over
all pairs of CATs. A smaller spread means more regular (repeatable) trajectories.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hub.analysis.network_bursts import NetworkBursts
from hub.analysis.spikes import AnalysisInputError, check_spikes


@dataclass(frozen=True)
class Cat:
    """One Center of Activity Trajectory.

    Attributes
    ----------
    t_ms : float64[k]
        Window centres (ms).
    x_um, y_um : float64[k]
        The centre of activity in each window (µm).
    """

    t_ms: np.ndarray
    x_um: np.ndarray
    y_um: np.ndarray

    def __len__(self) -> int:
        return int(self.t_ms.size)


def _positions(x_um, y_um, n_needed: int) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x_um, dtype=np.float64)
    y = np.asarray(y_um, dtype=np.float64)
    if x.ndim != 1 or x.shape != y.shape:
        raise AnalysisInputError(
            f"x_um and y_um must be 1-D of equal length, got shapes {x.shape} and {y.shape}"
        )
    if x.size < n_needed:
        raise AnalysisInputError(
            f"x_um/y_um must cover every channel id (need {n_needed}), got {x.size}"
        )
    return x, y


def center_of_activity(channel, t_ms, x_um, y_um, window_start_ms, dt_ms: float):
    """The centre of activity (mean position of the spiking channels) in time windows.

    Vectorised with cumulative sums over the (time-sorted) spikes.

    Parameters
    ----------
    channel : int array[k]
        Channel of each spike.
    t_ms : float array[k]
        Spike times, sorted.
    x_um, y_um : float array
        Position of every channel id.
    window_start_ms : float array[w]
        Each window is ``(window_start_ms[i], window_start_ms[i] + dt_ms]``.
    dt_ms : float
        Window length (> 0).

    Returns
    -------
    x_um, y_um : float64[w]
        The centre of activity of each window; NaN for an empty window.
    n_spikes : int64[w]
        Spikes in each window.
    """
    ch, t = check_spikes(channel, t_ms)
    if not dt_ms > 0:
        raise AnalysisInputError(f"dt_ms must be > 0, got {dt_ms}")
    x, y = _positions(x_um, y_um, int(ch.max()) + 1 if ch.size else 0)
    w0 = np.asarray(window_start_ms, dtype=np.float64)
    cx = np.concatenate([[0.0], np.cumsum(x[ch])])
    cy = np.concatenate([[0.0], np.cumsum(y[ch])])
    lo = np.searchsorted(t, w0, side="right")
    hi = np.searchsorted(t, w0 + dt_ms, side="right")
    n = hi - lo
    with np.errstate(invalid="ignore", divide="ignore"):
        ca_x = np.where(n > 0, (cx[hi] - cx[lo]) / n, np.nan)
        ca_y = np.where(n > 0, (cy[hi] - cy[lo]) / n, np.nan)
    return ca_x, ca_y, n


def center_of_activity_trajectories(
    channel,
    t_ms,
    x_um,
    y_um,
    network_bursts: NetworkBursts,
    time_scale_ms: float = 50.0,
    step_ms: float = 5.0,
) -> list[Cat]:
    """One CAT per network burst (see the module docstring for the exact construction).

    Parameters
    ----------
    channel : int array[k]
        Channel of each spike.
    t_ms : float array[k]
        Spike times, sorted.
    x_um, y_um : float array
        Position of every channel id.
    network_bursts : NetworkBursts
    time_scale_ms : float
        Window over which each centre of activity is computed (> 0).
    step_ms : float
        Step between window centres (> 0).

    Returns
    -------
    list of Cat
        In the order of ``network_bursts``; empty windows are left out of each CAT.
    """
    ch, t = check_spikes(channel, t_ms)
    if not time_scale_ms > 0:
        raise AnalysisInputError(f"time_scale_ms must be > 0, got {time_scale_ms}")
    if not step_ms > 0:
        raise AnalysisInputError(f"step_ms must be > 0, got {step_ms}")
    cats = []
    half = time_scale_ms / 2.0
    for start, end in zip(network_bursts.start_ms, network_bursts.end_ms, strict=True):
        tc = start + np.arange(int(np.floor((end - start) / step_ms + 1e-9)) + 1) * step_ms
        sl = slice(
            np.searchsorted(t, start - half, side="right"),
            np.searchsorted(t, end + half, side="right"),
        )
        cx, cy, n = center_of_activity(ch[sl], t[sl], x_um, y_um, tc - half, time_scale_ms)
        ok = n > 0
        cats.append(Cat(tc[ok], cx[ok], cy[ok]))
    return cats


def resample_cat(cat: Cat, n_points: int) -> np.ndarray:
    """A CAT resampled at evenly spaced points of its normalised time.

    Parameters
    ----------
    cat : Cat
    n_points : int

    Returns
    -------
    float64[n_points, 2]
        Positions, linearly interpolated; all NaN for an empty CAT.
    """
    if len(cat) == 0:
        return np.full((n_points, 2), np.nan)
    if len(cat) == 1:
        return np.tile([cat.x_um[0], cat.y_um[0]], (n_points, 1))
    u = (cat.t_ms - cat.t_ms[0]) / (cat.t_ms[-1] - cat.t_ms[0])
    grid = np.linspace(0.0, 1.0, n_points)
    return np.column_stack([np.interp(grid, u, cat.x_um), np.interp(grid, u, cat.y_um)])


def cat_spread(cats: list[Cat], n_points: int = 20, max_cats: int | None = 1000) -> float:
    """CAT regularity: the mean pairwise distance between CATs after resampling.

    Parameters
    ----------
    cats : list of Cat
        Empty ones are ignored.
    n_points : int
        Points each CAT is resampled to (>= 2, `resample_cat`).
    max_cats : int or None
        With more usable CATs, an evenly spaced subset of this many is used (keeps the cost
        bounded).

    Returns
    -------
    float
        Mean distance (µm; lower = more regular); NaN for fewer than two CATs.
    """
    if n_points < 2:
        raise AnalysisInputError(f"n_points must be >= 2, got {n_points}")
    usable = [c for c in cats if len(c) > 0]
    if max_cats is not None and len(usable) > max_cats:
        pick = np.linspace(0, len(usable) - 1, max_cats).round().astype(np.int64)
        usable = [usable[i] for i in pick]
    m = len(usable)
    if m < 2:
        return float("nan")
    arr = np.stack([resample_cat(c, n_points) for c in usable])  # (m, n_points, 2)
    total = 0.0
    for i in range(m - 1):
        d = np.linalg.norm(arr[i + 1 :] - arr[i], axis=2)  # (m-i-1, n_points)
        total += float(d.mean(axis=1).sum())
    return total / (m * (m - 1) / 2)
