"""Activity statistics used to calibrate the culture, with the paper's definitions (2.2, 3.2).

- burst of one neuron: at least 3 spikes within 20 ms; overlapping 3-spike windows merge;
- network burst: at least 30 % of the neurons inside a burst at the same time (1 ms bins);
  its *core* is the time the 30 % level is held, its *extent* runs from the start of the
  earliest to the end of the latest single-neuron burst overlapping the core (the usual MEA
  reading of "network-burst duration": first to last spike of the participating bursts);
- MFR: spikes/s per neuron (mean and s.d. over neurons); MBR: bursts/min per neuron, averaged.
These are this library's own implementation for calibration; hub/analysis owns the
reference analysis of recorded runs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BURST_MIN_SPIKES = 3
BURST_WINDOW_MS = 20.0
NETWORK_BURST_FRACTION = 0.3
BIN_MS = 1.0


@dataclass(frozen=True)
class Bursts:
    """Single-neuron bursts: neuron, start and end time (first and last spike), spike count."""

    neuron: np.ndarray
    start_ms: np.ndarray
    end_ms: np.ndarray


@dataclass(frozen=True)
class ActivitySummary:
    """The paper's spontaneous-activity figures for one recording."""

    duration_s: float
    mfr_mean: float
    mfr_sd: float
    mfr_exc: float
    mfr_inh: float
    mbr_per_min: float
    nb_per_min: float
    nb_duration_mean_ms: float  # extent
    nb_duration_sd_ms: float
    nb_core_mean_ms: float  # time at >= 30 % of neurons bursting
    nb_exc_spike_fraction: float
    n_network_bursts: int

    def as_dict(self) -> dict:
        """Plain dict for JSON."""
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


def find_bursts(neuron: np.ndarray, t_ms: np.ndarray) -> Bursts:
    """Bursts of every neuron (≥ 3 spikes within 20 ms, overlapping windows merged)."""
    order = np.lexsort((t_ms, neuron))
    nrn = np.asarray(neuron)[order].astype(np.int64)
    t = np.asarray(t_ms, dtype=np.float64)[order]
    span = BURST_MIN_SPIKES - 1
    if t.size <= span:
        z = np.zeros(0)
        return Bursts(z.astype(np.int64), z, z)
    ok = (nrn[span:] == nrn[:-span]) & (t[span:] - t[:-span] <= BURST_WINDOW_MS)
    marked = np.flatnonzero(ok)
    if marked.size == 0:
        z = np.zeros(0)
        return Bursts(z.astype(np.int64), z, z)
    new = np.ones(marked.size, dtype=bool)
    new[1:] = (np.diff(marked) > span) | (nrn[marked[1:]] != nrn[marked[:-1]])
    first = marked[new]
    last = marked[np.r_[np.flatnonzero(new)[1:] - 1, marked.size - 1]]
    return Bursts(nrn[first], t[first], t[last + span])


def network_bursts(bursts: Bursts, n_neurons: int, duration_ms: float):
    """Network bursts as (start_ms, end_ms) arrays: ≥ 30 % of neurons in a burst at once."""
    n_bins = int(np.ceil(duration_ms / BIN_MS)) + 2
    delta = np.zeros(n_bins + 1, dtype=np.int64)
    np.add.at(delta, np.floor(bursts.start_ms / BIN_MS).astype(np.int64), 1)
    np.add.at(delta, np.floor(bursts.end_ms / BIN_MS).astype(np.int64) + 1, -1)
    active = np.cumsum(delta)[:n_bins]
    above = active >= NETWORK_BURST_FRACTION * n_neurons
    edges = np.diff(np.r_[0, above.astype(np.int8), 0])
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1)
    return starts * BIN_MS, ends * BIN_MS


def network_burst_extent(bursts: Bursts, core_start: np.ndarray, core_end: np.ndarray):
    """Widen each network-burst core to the union of the single-neuron bursts overlapping it."""
    start = core_start.astype(np.float64).copy()
    end = core_end.astype(np.float64).copy()
    for i in range(core_start.size):
        hit = (bursts.start_ms < core_end[i]) & (bursts.end_ms >= core_start[i])
        if hit.any():
            start[i] = min(start[i], bursts.start_ms[hit].min())
            end[i] = max(end[i], bursts.end_ms[hit].max())
    return start, end


def summarize(
    neuron: np.ndarray, t_ms: np.ndarray, cell_type: np.ndarray, t0_ms: float, t1_ms: float
) -> ActivitySummary:
    """The paper's figures for spikes in [t0_ms, t1_ms) of a network with these cell types."""
    sel = (t_ms >= t0_ms) & (t_ms < t1_ms)
    neuron = np.asarray(neuron)[sel].astype(np.int64)
    t = np.asarray(t_ms)[sel] - t0_ms
    n = cell_type.size
    dur_s = (t1_ms - t0_ms) / 1000.0
    rate = np.bincount(neuron, minlength=n) / dur_s
    exc = cell_type == 0
    b = find_bursts(neuron, t)
    mbr = b.neuron.size / n / (dur_s / 60.0)
    core_start, core_end = network_bursts(b, n, t1_ms - t0_ms)
    nb_start, nb_end = network_burst_extent(b, core_start, core_end)
    dur = nb_end - nb_start
    core = core_end - core_start
    in_nb = np.zeros(t.size, dtype=bool)
    if nb_start.size:
        idx = np.searchsorted(nb_start, t, side="right") - 1
        ok = idx >= 0
        in_nb[ok] = t[ok] < nb_end[idx[ok]]
    nb_spikes = neuron[in_nb]
    exc_frac = float(np.mean(exc[nb_spikes])) if nb_spikes.size else float("nan")
    return ActivitySummary(
        duration_s=dur_s,
        mfr_mean=float(rate.mean()),
        mfr_sd=float(rate.std()),
        mfr_exc=float(rate[exc].mean()) if exc.any() else float("nan"),
        mfr_inh=float(rate[~exc].mean()) if (~exc).any() else float("nan"),
        mbr_per_min=float(mbr),
        nb_per_min=float(nb_start.size / (dur_s / 60.0)),
        nb_duration_mean_ms=float(dur.mean()) if dur.size else float("nan"),
        nb_duration_sd_ms=float(dur.std()) if dur.size else float("nan"),
        nb_core_mean_ms=float(core.mean()) if core.size else float("nan"),
        nb_exc_spike_fraction=exc_frac,
        n_network_bursts=int(nb_start.size),
    )


def psth(t_ms: np.ndarray, onsets_ms: np.ndarray, window_ms: float, bin_ms: float):
    """Peri-stimulus time histogram: (bin left edges, spikes per bin per trial)."""
    edges = np.arange(0.0, window_ms + bin_ms / 2, bin_ms)
    counts = np.zeros(edges.size - 1)
    for on in onsets_ms:
        rel = t_ms[(t_ms >= on) & (t_ms < on + window_ms)] - on
        counts += np.histogram(rel, bins=edges)[0]
    return edges[:-1], counts / max(1, len(onsets_ms))
