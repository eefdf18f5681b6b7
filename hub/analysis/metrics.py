"""The whole offline analysis of one record, and its summary metrics as a JSON-ready dict.

``analyze(...)`` runs every detector once and keeps the intermediate results (bursts, network
bursts, CATs, PSTH) for the figures; ``compute_metrics(...)`` returns just the metrics dict.

Metric keys (NaN becomes ``None`` so the dict is valid JSON):

==========================  ==================================================================
``duration_s``              record length ``t_stop_ms - t_start_ms`` in seconds
``n_channels``, ``n_spikes``
``mfr_hz``, ``mfr_sd_hz``   mean and s.d. over channels of each channel's firing rate (MFR)
``mfr_exc_hz``, ``mfr_inh_hz``  mean rate over excitatory / inhibitory channels (if cell types)
``nb_exc_spike_fraction``   fraction of spikes inside network bursts fired by excitatory
                            channels (if cell types; the paper: network bursts are dominated
                            by excitatory spikes)
``n_bursts``, ``mbr_per_min``   bursts, and bursts per minute per channel averaged over all
                            channels (MBR; silent channels count as 0)
``n_network_bursts``, ``mnbr_per_min``  network bursts and network bursts per minute (MNBR)
``nb_duration_ms``, ``nb_duration_sd_ms``  mean and s.d. of network-burst duration: the
                            extent, first to last spike of the participating bursts (the MEA
                            reading; see ``network_bursts``)
``nb_core_duration_ms``     mean time at or above the network-burst threshold (the core)
``nb_participation``        mean fraction of channels taking part in a network burst
``isi_median_ms``           median inter-spike interval within channels
``ibi_mean_ms``, ``ibi_cv``  mean and coefficient of variation of the intervals between
                            network-burst starts (IBI; the cores' starts)
``psth_peak_ms``            PSTH peak latency after the stimuli (only with ``stim_ms``)
``n_evoked_nb``             network bursts starting within ``evoked_max_latency_ms`` of a
                            stimulus (only with ``stim_ms``)
``cat_spread``              CAT regularity over all network bursts (only with positions);
                            with ``stim_ms`` also ``cat_spread_evoked`` and
                            ``cat_spread_spontaneous``
==========================  ==================================================================
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

import settings
from hub.analysis.bursts import BurstParams, bursting_rate_per_min, detect_bursts
from hub.analysis.center_of_activity import Cat, cat_spread, center_of_activity_trajectories
from hub.analysis.network_bursts import (
    NetworkBurstParams,
    NetworkBursts,
    detect_network_bursts,
    evoked_mask,
    inter_burst_intervals_ms,
)
from hub.analysis.spikes import (
    EXCITATORY,
    INHIBITORY,
    AnalysisInputError,
    Psth,
    check_span,
    check_spikes,
    firing_rates_hz,
    isi_ms,
    psth,
)
from settings import bounds


@dataclass(frozen=True)
class AnalysisParams:
    """Every analysis parameter in one place (defaults follow the paper).

    Attributes
    ----------
    bursts : BurstParams
        The single-channel burst definition.
    network_bursts : NetworkBurstParams
        The network-burst definition.
    psth_window_ms : (float, float)
        PSTH window after each stimulus.
    psth_bin_ms : float
        PSTH bin width.
    psth_min_latency_ms : float
        The PSTH peak is looked for from this latency on (skips a direct response).
    evoked_max_latency_ms : float
        A network burst starting within this time after a stimulus is evoked.
    cat_time_scale_ms, cat_step_ms : float
        Window and step of the centre-of-activity trajectories.
    cat_n_points : int
        Points each CAT is resampled to for the spread.
    rate_bin_ms : float
        Bin of the population-rate figure.
    """

    bursts: BurstParams = field(default_factory=BurstParams)
    network_bursts: NetworkBurstParams = field(default_factory=NetworkBurstParams)
    psth_window_ms: tuple[float, float] = (0.0, 300.0)
    psth_bin_ms: float = field(default=5.0, metadata=bounds(gt=0))
    psth_min_latency_ms: float = field(default=0.0, metadata=bounds(ge=0))
    evoked_max_latency_ms: float = field(default=200.0, metadata=bounds(ge=0))
    cat_time_scale_ms: float = field(default=50.0, metadata=bounds(gt=0))
    cat_step_ms: float = field(default=5.0, metadata=bounds(gt=0))
    cat_n_points: int = field(default=20, metadata=bounds(ge=2))
    rate_bin_ms: float = field(default=10.0, metadata=bounds(gt=0))

    @classmethod
    def from_dict(cls, d: dict | None) -> AnalysisParams:
        """Build from a config mapping such as a TOML ``[analysis]`` table.

        Parameters
        ----------
        d : dict or None
            Field values by name; nested tables ``bursts`` and ``network_bursts`` hold the
            fields of ``BurstParams`` and ``NetworkBurstParams``. None or missing keys: the
            defaults.

        Returns
        -------
        AnalysisParams

        Raises
        ------
        AnalysisInputError
            Naming the key (``analysis.bursts.min_spikes must be an integer >= 2, got 1``):
            an unknown key (with a "did you mean"), a value of the wrong type or out of its
            limits.
        """
        try:
            return settings.build(cls, dict(d or {}), "analysis.")
        except settings.ConfigError as exc:  # unknown key, type, limit: named
            raise AnalysisInputError(str(exc)) from None
        except AnalysisInputError as exc:  # a burst definition's own check, placed under analysis
            raise AnalysisInputError(f"analysis.{exc}") from None

    def to_dict(self) -> dict:
        """The parameters as nested plain dicts (what `from_dict` takes back).

        Returns
        -------
        dict
        """
        return dataclasses.asdict(self)


@dataclass
class AnalysisResult:
    """Everything ``analyze`` computed: the metrics dict and the pieces that figures need.

    Attributes
    ----------
    metrics : dict
        JSON-ready metrics (NaN as None; keys in the module docstring).
    rates_hz : float64[n_channels]
        Firing rate of each channel.
    bursts : BURST_DTYPE array
        Single-channel bursts.
    network_bursts : NetworkBursts
    cats : list of Cat or None
        Centre-of-activity trajectories of the network bursts, with positions.
    psth : Psth or None
        With stimulus times.
    evoked : bool[n_network_bursts] or None
        Which network bursts are evoked, with stimulus times.
    """

    metrics: dict
    rates_hz: np.ndarray
    bursts: np.ndarray
    network_bursts: NetworkBursts
    cats: list[Cat] | None = None
    psth: Psth | None = None
    evoked: np.ndarray | None = None


def _clean(x):
    """Plain Python float/int for JSON, NaN -> None."""
    if isinstance(x, (int, np.integer)):
        return int(x)
    x = float(x)
    return None if math.isnan(x) else x


def _mean_sd(values: np.ndarray) -> tuple[float, float]:
    if values.size == 0:
        return float("nan"), float("nan")
    return float(values.mean()), float(values.std())


def _exc_fraction_in(ch: np.ndarray, t: np.ndarray, ct: np.ndarray, nbs: NetworkBursts) -> float:
    """Fraction of the spikes inside network bursts that excitatory channels fired."""
    if len(nbs) == 0:
        return math.nan
    idx = np.searchsorted(nbs.start_ms, t, side="right") - 1
    inside = (idx >= 0) & (t <= nbs.end_ms[np.maximum(idx, 0)])
    if not inside.any():
        return math.nan
    return float(np.mean(ct[ch[inside]] == EXCITATORY))


def analyze(
    channel,
    t_ms,
    n_channels: int,
    t_start_ms: float,
    t_stop_ms: float,
    cell_type=None,
    x_um=None,
    y_um=None,
    stim_ms=None,
    params: AnalysisParams | None = None,
) -> AnalysisResult:
    """Run the full offline analysis of spikes in ``[t_start_ms, t_stop_ms)``.

    Parameters
    ----------
    channel : int array[k]
        Channel index (0..n_channels-1) of each spike.
    t_ms : float array[k]
        Time of each spike (ms); spikes outside the span are ignored.
    n_channels : int
        Channels recorded (silent ones count in the means).
    t_start_ms, t_stop_ms : float
        The analysed span.
    cell_type : uint8[n_channels], optional
        0 excitatory, 1 inhibitory: adds the per-population rates and the excitatory share
        of network-burst spikes.
    x_um, y_um : float[n_channels], optional
        Channel positions: add the centre-of-activity trajectories and their spread.
    stim_ms : float array, optional
        Stimulus times: add the PSTH and the evoked / spontaneous split.
    params : AnalysisParams, optional
        Default the paper's.

    Returns
    -------
    AnalysisResult

    Raises
    ------
    AnalysisInputError
        Malformed spikes, span or per-channel arrays (the message names the argument).
    """
    p = params or AnalysisParams()
    ch, t = check_spikes(channel, t_ms, n_channels)
    duration_ms = check_span(t_start_ms, t_stop_ms)
    inside = (t >= t_start_ms) & (t < t_stop_ms)
    if not inside.all():
        ch, t = ch[inside], t[inside]

    rates = firing_rates_hz(ch, t, n_channels, t_start_ms, t_stop_ms)
    bursts = detect_bursts(ch, t, p.bursts)
    nbs = detect_network_bursts(bursts, n_channels, p.network_bursts)
    mfr, mfr_sd = _mean_sd(rates)
    nb_dur, nb_dur_sd = _mean_sd(nbs.duration_ms)
    ibi = inter_burst_intervals_ms(nbs)
    ibi_mean, ibi_sd = _mean_sd(ibi)
    isis = isi_ms(ch, t)
    m = {
        "duration_s": duration_ms / 1000.0,
        "n_channels": int(n_channels),
        "n_spikes": int(t.size),
        "mfr_hz": mfr,
        "mfr_sd_hz": mfr_sd,
        "n_bursts": int(bursts.size),
        "mbr_per_min": float(bursting_rate_per_min(bursts, n_channels, duration_ms).mean()),
        "n_network_bursts": len(nbs),
        "mnbr_per_min": len(nbs) / (duration_ms / 60_000.0),
        "nb_duration_ms": nb_dur,
        "nb_duration_sd_ms": nb_dur_sd,
        "nb_core_duration_ms": _mean_sd(nbs.core_duration_ms)[0],
        "nb_participation": float(nbs.n_channels.mean() / n_channels) if len(nbs) else math.nan,
        "isi_median_ms": float(np.median(isis)) if isis.size else math.nan,
        "ibi_mean_ms": ibi_mean,
        # one interval has no spread to speak of: "CV 0, periodic" from two network bursts
        "ibi_cv": ibi_sd / ibi_mean if ibi.size >= 2 and ibi_mean > 0 else math.nan,
    }
    if cell_type is not None:
        ct = np.asarray(cell_type)
        if ct.shape != (n_channels,):
            raise AnalysisInputError(
                f"cell_type must have one entry per channel ({n_channels}), got shape {ct.shape}"
            )
        m["mfr_exc_hz"] = _mean_sd(rates[ct == EXCITATORY])[0]
        m["mfr_inh_hz"] = _mean_sd(rates[ct == INHIBITORY])[0]
        m["nb_exc_spike_fraction"] = _exc_fraction_in(ch, t, ct, nbs)

    result = AnalysisResult(m, rates, bursts, nbs)
    if stim_ms is not None:
        stim = np.asarray(stim_ms, dtype=np.float64)
        result.psth = psth(ch, t, stim, n_channels, p.psth_window_ms, p.psth_bin_ms)
        m["psth_peak_ms"] = result.psth.peak_latency_ms(p.psth_min_latency_ms)
        result.evoked = evoked_mask(nbs, stim, p.evoked_max_latency_ms)
        m["n_evoked_nb"] = int(result.evoked.sum())
    if x_um is not None and y_um is not None:
        cats = center_of_activity_trajectories(
            ch, t, x_um, y_um, nbs, p.cat_time_scale_ms, p.cat_step_ms
        )
        result.cats = cats
        m["cat_spread"] = cat_spread(cats, p.cat_n_points)
        if result.evoked is not None:
            ev = result.evoked
            m["cat_spread_evoked"] = cat_spread(
                [c for c, e in zip(cats, ev, strict=True) if e], p.cat_n_points
            )
            m["cat_spread_spontaneous"] = cat_spread(
                [c for c, e in zip(cats, ev, strict=True) if not e], p.cat_n_points
            )
    result.metrics = {k: _clean(v) for k, v in m.items()}
    return result


def compute_metrics(
    channel,
    t_ms,
    n_channels: int,
    t_start_ms: float,
    t_stop_ms: float,
    cell_type=None,
    x_um=None,
    y_um=None,
    stim_ms=None,
    params: AnalysisParams | None = None,
) -> dict:
    """The metrics dict of ``analyze``.

    Parameters
    ----------
    channel, t_ms, n_channels, t_start_ms, t_stop_ms, cell_type, x_um, y_um, stim_ms, params
        As for `analyze`.

    Returns
    -------
    dict
        JSON-ready (see the module docstring for the keys).
    """
    return analyze(
        channel, t_ms, n_channels, t_start_ms, t_stop_ms, cell_type, x_um, y_um, stim_ms, params
    ).metrics
