"""Spike-train basics: input checks, firing rates, ISIs, PSTH and instantaneous rate.

Spikes are two parallel arrays: ``channel`` (integer channel id) and ``t_ms`` (float64 absolute
time in milliseconds, sorted by time). Every function here is vectorised numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from devices.culture import EXCITATORY, INHIBITORY  # the wire contract's cell-type codes

POPULATIONS = ("all", "exc", "inh")


class AnalysisInputError(ValueError):
    """Bad input to an analysis function; the message names the argument and the reason."""


def check_spikes(channel, t_ms, n_channels: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Validate spike arrays.

    Parameters
    ----------
    channel : int array_like[k]
        Channel of each spike (>= 0, and < ``n_channels`` when given).
    t_ms : float array_like[k]
        Spike times, finite and sorted.
    n_channels : int, optional
        Channels recorded (>= 1).

    Returns
    -------
    channel : int64[k]
    t_ms : float64[k]

    Raises
    ------
    AnalysisInputError
        When the arrays differ in length, are not 1-D, hold non-finite times, negative
        channels, channels ``>= n_channels`` or times not sorted.
    """
    ch = np.asarray(channel)
    t = np.asarray(t_ms, dtype=np.float64)
    if ch.ndim != 1 or t.ndim != 1:
        raise AnalysisInputError(
            f"channel and t_ms must be 1-D, got shapes {ch.shape} and {t.shape}"
        )
    if ch.shape != t.shape:
        raise AnalysisInputError(
            f"channel and t_ms must have equal length, got {ch.size} and {t.size}"
        )
    if ch.size and not np.issubdtype(ch.dtype, np.integer):
        raise AnalysisInputError(f"channel must be integers, got dtype {ch.dtype}")
    ch = ch.astype(np.int64, copy=False)
    if t.size:
        if not np.all(np.isfinite(t)):
            raise AnalysisInputError("t_ms must be finite, got NaN or inf")
        if np.any(np.diff(t) < 0):
            raise AnalysisInputError("t_ms must be sorted by time (non-decreasing)")
        if ch.min() < 0:
            raise AnalysisInputError(f"channel must be >= 0, got {ch.min()}")
        if n_channels is not None and ch.max() >= n_channels:
            raise AnalysisInputError(f"channel must be < n_channels={n_channels}, got {ch.max()}")
    if n_channels is not None and n_channels < 1:
        raise AnalysisInputError(f"n_channels must be >= 1, got {n_channels}")
    return ch, t


def check_span(t_start_ms: float, t_stop_ms: float) -> float:
    """Check an analysed span.

    Parameters
    ----------
    t_start_ms, t_stop_ms : float
        Finite, ``t_stop_ms > t_start_ms``.

    Returns
    -------
    float
        The duration (ms).
    """
    if not (np.isfinite(t_start_ms) and np.isfinite(t_stop_ms)):
        raise AnalysisInputError(
            f"t_start_ms and t_stop_ms must be finite, got {t_start_ms}, {t_stop_ms}"
        )
    if t_stop_ms <= t_start_ms:
        raise AnalysisInputError(f"t_stop_ms must be > t_start_ms, got {t_stop_ms} <= {t_start_ms}")
    return float(t_stop_ms - t_start_ms)


def population_mask(cell_type, n_channels: int, population: str) -> np.ndarray:
    """The channels of a population.

    Parameters
    ----------
    cell_type : uint8[n_channels] or None
        0 excitatory, 1 inhibitory; needed for ``"exc"`` and ``"inh"``.
    n_channels : int
    population : str
        ``"all"``, ``"exc"`` or ``"inh"``.

    Returns
    -------
    bool[n_channels]
    """
    if population not in POPULATIONS:
        raise AnalysisInputError(f"population must be one of {POPULATIONS}, got {population!r}")
    if population == "all":
        return np.ones(n_channels, dtype=bool)
    if cell_type is None:
        raise AnalysisInputError(f"population={population!r} needs cell_type, got None")
    ct = np.asarray(cell_type)
    if ct.shape != (n_channels,):
        raise AnalysisInputError(
            f"cell_type must have one entry per channel ({n_channels}), got shape {ct.shape}"
        )
    return ct == (EXCITATORY if population == "exc" else INHIBITORY)


def firing_rates_hz(channel, t_ms, n_channels: int, t_start_ms: float, t_stop_ms: float):
    """Mean firing rate of every channel over ``[t_start_ms, t_stop_ms)``.

    Parameters
    ----------
    channel, t_ms : array_like[k]
        The spikes (`check_spikes`).
    n_channels : int
    t_start_ms, t_stop_ms : float
        The span; spikes outside it are not counted.

    Returns
    -------
    float64[n_channels]
        Spikes per second (silent channels give 0).
    """
    ch, t = check_spikes(channel, t_ms, n_channels)
    duration_s = check_span(t_start_ms, t_stop_ms) / 1000.0
    inside = (t >= t_start_ms) & (t < t_stop_ms)
    counts = np.bincount(ch[inside], minlength=n_channels)
    return counts / duration_s


def isi_ms(channel, t_ms) -> np.ndarray:
    """All inter-spike intervals within each channel.

    Parameters
    ----------
    channel, t_ms : array_like[k]
        The spikes (`check_spikes`).

    Returns
    -------
    float64 array
        The intervals (ms), channel by channel, concatenated.
    """
    ch, t = check_spikes(channel, t_ms)
    if t.size < 2:
        return np.empty(0)
    order = np.lexsort((t, ch))
    ch, t = ch[order], t[order]
    same = ch[1:] == ch[:-1]
    return np.diff(t)[same]


def interval_histogram(intervals_ms, bin_ms: float, max_ms: float):
    """Histogram of intervals on ``[0, max_ms]``.

    Parameters
    ----------
    intervals_ms : float array_like
    bin_ms, max_ms : float
        Bin width and upper end (> 0).

    Returns
    -------
    counts : int64[n_bins]
    edges_ms : float64[n_bins + 1]
        Intervals beyond ``max_ms`` are left out.
    """
    if bin_ms <= 0:
        raise AnalysisInputError(f"bin_ms must be > 0, got {bin_ms}")
    if max_ms <= 0:
        raise AnalysisInputError(f"max_ms must be > 0, got {max_ms}")
    n_bins = max(1, int(np.ceil(max_ms / bin_ms - 1e-9)))
    edges = np.arange(n_bins + 1) * bin_ms
    counts, _ = np.histogram(np.asarray(intervals_ms, dtype=np.float64), bins=edges)
    return counts, edges


@dataclass(frozen=True)
class Psth:
    """Post-stimulus time histogram.

    Attributes
    ----------
    edges_ms : float64[n_bins + 1]
        Bin edges relative to the stimulus.
    counts : int64[n_bins]
        ``counts[i]`` spikes fell in ``[edges_ms[i], edges_ms[i+1])`` after a stimulus, summed
        over all stimuli and all channels counted.
    rate_hz : float64[n_bins]
        That per stimulus, per channel and per second (the mean firing rate of a channel in
        that bin).
    n_stimuli, n_channels : int
        Stimuli and channels counted.
    """

    edges_ms: np.ndarray
    counts: np.ndarray
    rate_hz: np.ndarray
    n_stimuli: int
    n_channels: int

    @property
    def centers_ms(self) -> np.ndarray:
        """The bins' centres relative to the stimulus (ms)."""
        return 0.5 * (self.edges_ms[1:] + self.edges_ms[:-1])

    def peak_latency_ms(self, min_latency_ms: float = 0.0) -> float:
        """The latency of the PSTH's peak.

        Parameters
        ----------
        min_latency_ms : float
            Only bins that start at or after it count (skips the direct response during the
            pulse itself).

        Returns
        -------
        float
            Centre of the fullest such bin (ms); NaN when they hold no spikes.
        """
        usable = self.edges_ms[:-1] >= min_latency_ms
        if not usable.any() or self.counts[usable].sum() == 0:
            return float("nan")
        idx = np.flatnonzero(usable)[np.argmax(self.counts[usable])]
        return float(self.centers_ms[idx])


def psth(
    channel,
    t_ms,
    stim_ms,
    n_channels: int,
    window_ms: tuple[float, float] = (0.0, 200.0),
    bin_ms: float = 5.0,
    channels=None,
) -> Psth:
    """PSTH of spikes around stimulus times.

    Parameters
    ----------
    channel, t_ms : array_like[k]
        The spikes (`check_spikes`).
    stim_ms : float array_like
        Stimulus times (absolute ms).
    n_channels : int
    window_ms : (float, float)
        Limits relative to each stimulus, e.g. ``(-50, 200)``.
    bin_ms : float
        Bin width.
    channels : int array_like, optional
        Channel ids to count (default all ``n_channels``).

    Returns
    -------
    Psth
    """
    ch, t = check_spikes(channel, t_ms, n_channels)
    stim = np.sort(np.asarray(stim_ms, dtype=np.float64).ravel())
    lo_ms, hi_ms = window_ms
    if not hi_ms > lo_ms:
        raise AnalysisInputError(f"window_ms must be (lo, hi) with hi > lo, got {window_ms}")
    if bin_ms <= 0:
        raise AnalysisInputError(f"bin_ms must be > 0, got {bin_ms}")
    if channels is not None:
        keep_ch = np.zeros(n_channels, dtype=bool)
        keep_ch[np.asarray(channels, dtype=np.int64)] = True
        t = t[keep_ch[ch]]
        n_counted = int(keep_ch.sum())
    else:
        n_counted = n_channels
    n_bins = max(1, int(np.ceil((hi_ms - lo_ms) / bin_ms - 1e-9)))
    edges = lo_ms + np.arange(n_bins + 1) * bin_ms
    first = np.searchsorted(t, stim + lo_ms, side="left")
    last = np.searchsorted(t, stim + edges[-1], side="left")
    lengths = last - first
    if lengths.sum():
        # Gather every (spike, stimulus) pair inside the window without a Python loop.
        offsets = np.repeat(first - np.cumsum(lengths) + lengths, lengths)
        idx = np.arange(lengths.sum()) + offsets
        rel = t[idx] - np.repeat(stim, lengths)
        counts, _ = np.histogram(rel, bins=edges)
    else:
        counts = np.zeros(n_bins, dtype=np.int64)
    denom = max(stim.size, 1) * max(n_counted, 1) * bin_ms / 1000.0
    return Psth(edges, counts, counts / denom, int(stim.size), n_counted)


def instantaneous_rate(
    channel,
    t_ms,
    n_channels: int,
    t_start_ms: float,
    t_stop_ms: float,
    bin_ms: float = 10.0,
    population: str = "all",
    cell_type=None,
    per_channel: bool = False,
):
    """Spiking rate of a population in consecutive bins.

    Parameters
    ----------
    channel, t_ms : array_like[k]
        The spikes (`check_spikes`).
    n_channels : int
    t_start_ms, t_stop_ms : float
        The span, cut into bins of ``bin_ms``.
    bin_ms : float
    population : str
        ``"all"``, ``"exc"`` or ``"inh"`` (the last two need ``cell_type``).
    cell_type : uint8[n_channels], optional
    per_channel : bool
        Divide by the number of channels in the population.

    Returns
    -------
    centers_ms : float64[n_bins]
    rate_hz : float64[n_bins]
        The population's total spikes per second in each bin (per channel with
        ``per_channel=True``).
    """
    ch, t = check_spikes(channel, t_ms, n_channels)
    check_span(t_start_ms, t_stop_ms)
    if bin_ms <= 0:
        raise AnalysisInputError(f"bin_ms must be > 0, got {bin_ms}")
    mask = population_mask(cell_type, n_channels, population)
    keep = mask[ch] & (t >= t_start_ms) & (t < t_stop_ms)
    n_bins = max(1, int(np.ceil((t_stop_ms - t_start_ms) / bin_ms - 1e-9)))
    idx = np.minimum(((t[keep] - t_start_ms) // bin_ms).astype(np.int64), n_bins - 1)
    counts = np.bincount(idx, minlength=n_bins)
    rate = counts / (bin_ms / 1000.0)
    if per_channel:
        rate = rate / max(int(mask.sum()), 1)
    centers = t_start_ms + (np.arange(n_bins) + 0.5) * bin_ms
    return centers, rate
