"""Offline analysis of one recorded run: ``metrics.json``, figures and a ``report.html``.

``analyze_run(run_dir, out_dir=None)`` is what ``neuvision analyze RUN_DIR [--out DIR]`` calls.
It reads the record with ``hub.record.read_run`` and uses, from it:

- the culture's spikes (``SpikeBatch`` received or late), in absolute ms; the analysed span is
  from the first batch's ``t0_s`` to the last batch's ``t1_s``;
- the culture's ``Description`` (channel ids, positions, cell types), when there is one;
  channel ids are mapped to indices ``0..n-1`` in the order of the description;
- the sent ``Stimulation`` messages: each distinct pulse onset, its step window's
  ``t0_s`` (in ms) plus ``onset_ms``, is one stimulus of the PSTH (pulses into several
  channels at the same time count once) -- unless the stimuli come closer together than the
  PSTH's window (a closed loop stimulating every step): then no PSTH, and
  ``psth_not_computed`` says why; network bursts whose extents a channel bursting
  throughout has stretched are said so (``nb_extents_stretched``);
- in a closed loop (a body with poses), the loop figure (``loop.png``: sensor ranges,
  pulses, the Center of Activity, wheel commands on one time axis) and the map of the
  stimulation sites (``stimulation_sites.png``);
- the body's poses: the behaviour metrics of ``lab.behaviour`` (``body_*``; arena metrics
  and the trajectory picture when the run's world is known);
- the manifest's config and timing, shown in the report.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hub.analysis.figures import FORMATS, plot_all
from hub.analysis.metrics import AnalysisParams, analyze
from hub.analysis.output import save_figure, write_whole
from hub.analysis.report import write_report
from hub.analysis.spikes import AnalysisInputError
from hub.decoding import WINDOW_MS
from hub.protocol import SpikeBatch, Stimulation
from hub.record import DATA_DIRECTIONS, read_run
from lab.behaviour import behaviour_metrics, world_of
from lab.loop_figure import loop_series, plot_loop, plot_stimulation_sites
from sim_robot.render import TRAJECTORY_SAVE, trajectory_figure

ANALYSIS_DIR = "analysis"
METRICS_FILE = "metrics.json"
REPORT_FILE = "report.html"


def stimulus_onsets_ms(stimulations) -> tuple[np.ndarray, np.ndarray]:
    """Distinct pulse onsets and the stimulated channel ids of recorded stimulations.

    Parameters
    ----------
    stimulations : list of hub.protocol.Stimulation
        A pulse starts ``onset_ms`` into its message's window (``t0_s``): the same run
        time the culture's spikes are stamped with.

    Returns
    -------
    onsets_ms : float64 array
        Distinct onsets (absolute ms, sorted): pulses into several channels at once count
        once.
    channels : uint32 array
        The distinct stimulated channel ids.
    """
    onsets = [m.t0_s * 1e3 + m.onset_ms.astype(np.float64) for m in stimulations]
    chans = [m.channel for m in stimulations]
    if not onsets or not sum(o.size for o in onsets):
        return np.empty(0), np.empty(0, np.uint32)
    return np.unique(np.concatenate(onsets)), np.unique(np.concatenate(chans))


def psth_applies(stim_ms: np.ndarray | None, params: AnalysisParams) -> str:
    """Why no PSTH is computed (empty: it is): stimuli closer together than the PSTH's
    window (a closed loop stimulates every step) make every response overlap the next.

    Parameters
    ----------
    stim_ms : float array or None
        The stimulus onsets (ms, sorted); fewer than two: a PSTH applies.
    params : AnalysisParams
        Its ``psth_window_ms`` is compared with the median interval between onsets.
    """
    if stim_ms is None or stim_ms.size < 2:
        return ""
    window_ms = params.psth_window_ms[1] - params.psth_window_ms[0]
    median_ms = float(np.median(np.diff(stim_ms)))
    if median_ms >= window_ms:
        return ""
    return (
        f"stimuli every {median_ms:g} ms (median), closer than the PSTH window of "
        f"{window_ms:g} ms: their responses overlap"
    )


#: extents this many times their cores' length (and over a second, in the median) are
#: stretched by a channel that bursts throughout, not by the network burst itself
STRETCHED_RATIO = 20.0


def extents_note(nbs) -> str:
    """What to read instead when the network bursts' extents are stretched (empty: they
    are not): a channel stimulated every step of a closed loop bursts for seconds and takes
    part in every network burst it overlaps (docs/analysis.md, "read the core")."""
    if len(nbs) == 0:
        return ""
    extent_ms = float(np.median(nbs.duration_ms))
    core_ms = float(np.median(nbs.core_duration_ms))
    if extent_ms < 1000.0 or extent_ms < STRETCHED_RATIO * max(core_ms, 1e-9):
        return ""
    return (
        f"network-burst extents span {extent_ms / 1e3:.1f} s (median) against cores of "
        f"{core_ms:.0f} ms: channels bursting throughout (stimulated every step in a closed "
        "loop) stretch them. Read the cores (nb_core_duration_ms, the IBI); "
        "nb_duration_ms and the CATs follow the extents"
    )


def _culture_arrays(culture, channel: np.ndarray):
    """Map channel ids to indices; return (index per spike, keep mask, n, cell_type, x, y)."""
    if culture is None or culture.channel is None or culture.channel.size == 0:
        n = int(channel.max()) + 1 if channel.size else 1
        return channel.astype(np.int64), np.ones(channel.size, bool), n, None, None, None
    ids = np.asarray(culture.channel, dtype=np.int64)
    order = np.argsort(ids)
    pos = np.searchsorted(ids[order], channel)
    pos = np.minimum(pos, ids.size - 1)
    keep = ids[order][pos] == channel
    index = order[pos]
    ct = None if culture.cell_type is None else np.asarray(culture.cell_type, dtype=np.uint8)
    x = np.asarray(culture.x_um, dtype=np.float64)
    y = np.asarray(culture.y_um, dtype=np.float64)
    return index, keep, int(ids.size), ct, x, y


def _span_ms(batches, manifest: dict, period_ms: float | None) -> tuple[float, float]:
    if batches:
        return (
            min(b.t0_s for b in batches) * 1e3,
            max(b.t1_s for b in batches) * 1e3,
        )
    steps = manifest.get("steps") or 0
    if period_ms and steps:
        return 0.0, steps * period_ms
    raise AnalysisInputError("the run has no spike batches and no steps: nothing to analyse")


def _trajectory(rec, config: dict, out: Path, title: str, metrics: dict) -> list[Path]:
    """Add the body's behaviour metrics; draw its trajectory when the run's world is known."""
    t_s, poses = rec.trajectory()
    if len(t_s) < 2:
        return []
    world = world_of(config)
    body = rec.descriptions().get("body")
    for key, value in behaviour_metrics(t_s, poses, world, body).items():
        if isinstance(value, (int, float, bool)):
            metrics[f"body_{key}"] = value
    if world is None:
        return []
    figure = trajectory_figure(world, t_s, poses, title=title)
    return [save_figure(figure, out / f"trajectory.{fmt}", **TRAJECTORY_SAVE) for fmt in FORMATS]


def analyze_run(
    run_dir,
    out_dir=None,
    params: AnalysisParams | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict:
    """Analyse a recorded run; write ``metrics.json``, figures and ``report.html``.

    Parameters
    ----------
    run_dir : the run folder (``manifest.json`` + ``record.nvrec``).
    out_dir : where to write; default ``RUN_DIR/analysis``. Created if needed.
    params : analysis parameters; default ``AnalysisParams.from_dict(config["analysis"])`` when
        the run's config has an ``analysis`` table, else the paper's defaults.
    progress : callable, optional
        ``progress(stage)`` as each stage starts (reading, analysing, figures, report): a
        long record takes a while.

    Returns
    -------
    dict with ``metrics`` (the dict written to ``metrics.json``), ``out_dir``, ``metrics_path``,
    ``report_path`` and ``figures`` (paths written).
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise AnalysisInputError(f"run_dir {run_dir} is not a folder")
    say = progress or (lambda stage: None)
    say("reading the record")
    rec = read_run(run_dir)
    manifest = rec.manifest
    short = rec.short_note()  # a record cut short: analysed, and said
    if short and not rec.steps_recorded():
        raise AnalysisInputError(
            f"the record holds none of the run's {manifest['steps']} steps (empty, or "
            "damaged from its start): nothing to analyse"
        )
    config = manifest.get("config", {}) or {}
    if params is None:
        params = AnalysisParams.from_dict(config.get("analysis"))
    out = Path(out_dir) if out_dir is not None else run_dir / ANALYSIS_DIR
    out.mkdir(parents=True, exist_ok=True)
    period_ms = config.get("loop", {}).get("period_ms")

    batches = rec.decoded(SpikeBatch, *DATA_DIRECTIONS)
    t_start_ms, t_stop_ms = _span_ms(batches, manifest, period_ms)
    channel, t_ms = rec.spikes()  # in time order
    channel = channel.astype(np.int64)
    culture = rec.descriptions().get("culture")
    index, keep, n_channels, cell_type, x_um, y_um = _culture_arrays(culture, channel)
    index, t_ms = index[keep], t_ms[keep]

    # the stimulations of the steps analysed: not one sent (pipelined) for a step the
    # run ended before (an interrupt, a stop), whose spikes never came
    stimulations = [s for s in rec.decoded(Stimulation, "tx") if s.t0_s * 1e3 < t_stop_ms]
    stim_ms, stim_ids = None, None
    if stimulations:
        stim_ms, stim_ids = stimulus_onsets_ms(stimulations)
        if stim_ms.size == 0:
            stim_ms = None
    n_stimuli = int(stim_ms.size) if stim_ms is not None else 0
    psth_note = psth_applies(stim_ms, params)
    if psth_note:  # stimuli closer than the PSTH's window: responses overlap, no PSTH
        stim_ms = None

    say(f"analysing {t_ms.size:,} spikes on {n_channels:,} channels")
    result = analyze(
        index, t_ms, n_channels, t_start_ms, t_stop_ms, cell_type, x_um, y_um, stim_ms, params
    )
    metrics = dict(result.metrics)
    metrics["n_stimuli"] = n_stimuli
    if psth_note:
        metrics["psth_not_computed"] = psth_note
    metrics["n_unknown_channel_spikes"] = int((~keep).sum())
    stretched = extents_note(result.network_bursts)
    if stretched:
        metrics["nb_extents_stretched"] = stretched
    if short:
        metrics["record_short"] = short
    if damaged := rec.damage_note():
        metrics["record_damaged"] = damaged
    # a run killed, interrupted or still going is analysed as far as it went: said here,
    # for a script gathering metrics over runs
    metrics["run_outcome"] = manifest.get("outcome", "unknown")

    stim_channels = None
    if stim_ids is not None and culture is not None and culture.channel is not None:
        stim_channels = np.flatnonzero(np.isin(culture.channel, stim_ids))
    say("drawing the figures")
    figures = plot_all(
        out, index, t_ms, result, t_start_ms, t_stop_ms, cell_type, x_um, y_um, stim_channels
    )
    name = manifest.get("name") or run_dir.name
    title = f"{name} (seed {manifest.get('seed')})"
    figures += _trajectory(rec, config, out, title, metrics)
    if rec.trajectory()[0].size > 1:  # a closed loop: a body in it
        decoding = config.get("decoding", {}).get("params") or {}
        window_ms = float(decoding.get("window_ms", WINDOW_MS))
        centre_tau_s = float(decoding.get("centre_tau_s", 0.0))
        series = loop_series(rec, ca_window_ms=window_ms, centre_tau_s=centre_tau_s)
        figures += plot_loop(
            series, out / "loop", title=title, ca_window_ms=window_ms, centre_tau_s=centre_tau_s
        )
        figures += plot_stimulation_sites(rec, series, out / "stimulation_sites")

    metrics_path = out / METRICS_FILE
    write_whole(metrics_path, json.dumps(metrics, indent=2))
    timing = dict(manifest.get("timing") or {})
    for key in ("outcome", "reason", "start_utc", "end_utc", "steps"):
        if manifest.get(key) not in (None, ""):
            timing[key] = manifest[key]
    if short:
        timing["record"] = short
    say("writing the report")
    report_path = write_report(
        out / REPORT_FILE, metrics, config, figures, title=f"NeuVision run {name}", timing=timing
    )
    return {
        "metrics": metrics,
        "out_dir": out,
        "metrics_path": metrics_path,
        "report_path": report_path,
        "figures": figures,
    }
