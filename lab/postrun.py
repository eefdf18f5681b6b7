"""What a finished run leaves beside its record: ``summary.json`` and pictures.

Called by ``neuvision run`` and ``neuvision hub`` after every run that did not
fault, and usable on any run folder (:func:`summarize_run`). Everything is
computed from the record, so a summary always describes what was recorded:

- the loop's timing figures and counts (always);
- the behaviour metrics of any body that recorded its poses (``lab.behaviour``), with the
  arena metrics and ``trajectory.png``/``.svg`` when its world is known;
- ``raster.png``/``.svg`` of the culture's activity when spikes were recorded, with the
  network bursts the burst observer reported during the run (its ``network_burst`` events;
  none when live analysis was off — ``neuvision analyze`` detects them offline).

A part that fails (a figure, say) is named in ``summary.json`` and in the manifest
(``postrun_failures``); the rest is written, and the run keeps its outcome.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from hub.analysis.figures import plot_raster
from hub.analysis.network_bursts import NetworkBursts
from hub.analysis.output import save_figure, write_whole
from hub.protocol import Stimulation
from hub.record import read_run, write_manifest
from lab.behaviour import behaviour_metrics, world_of
from sim_robot.render import TRAJECTORY_SAVE, trajectory_figure

log = logging.getLogger(__name__)

SUMMARY_FILE = "summary.json"


def after_run(result, cfg) -> dict:
    """Summarise a finished run into its folder.

    Parameters
    ----------
    result : hub.loop.RunResult
        Its ``run_dir`` (None: nothing was recorded).
    cfg : hub.config.ExperimentConfig
        Nothing is written when ``record.enabled`` is off.

    Returns
    -------
    dict
        The summary (`summarize_run`), or ``{}``.
    """
    if result.run_dir is None or not cfg.record.enabled:
        return {}
    return summarize_run(result.run_dir)


def summarize_run(run_dir: str | Path) -> dict:
    """Write ``summary.json`` and the pictures of a recorded run.

    Each part (behaviour, trajectory, raster) is done on its own: one that fails is named
    in the summary's ``failures`` and in the manifest's ``postrun_failures`` (with its
    error) and logged, and the rest is still written. A completed run keeps its summary.

    Parameters
    ----------
    run_dir : str or Path
        A run folder (``manifest.json`` + record).

    Returns
    -------
    dict
        What ``summary.json`` holds: name, seed, outcome, steps, simulated time, timing,
        counts, ``behaviour`` (`lab.behaviour.behaviour_metrics`, when poses were recorded),
        ``spikes``, ``stimulation_pulses``, the ``figures`` written and ``failures``.
    """
    run_dir = Path(run_dir)
    rec = read_run(run_dir)
    m = rec.manifest
    config = m.get("config", {})
    period_ms = config.get("loop", {}).get("period_ms", 0.0)
    summary = {
        "name": m.get("name"),
        "seed": m.get("seed"),
        "outcome": m.get("outcome"),
        "steps": m.get("steps"),
        "simulated_s": (m.get("steps") or 0) * period_ms / 1e3,
        "timing": m.get("timing", {}),
        "counts": m.get("counts", {}),
        "figures": [],
        "failures": [],
    }

    def attempt(part: str, work) -> None:
        try:
            work()
        except Exception as exc:  # a figure must not cost the run its summary
            log.warning("summary of %s: %s failed: %r", run_dir.name, part, exc)
            summary["failures"].append({"part": part, "error": f"{type(exc).__name__}: {exc}"})

    t_s, poses = rec.trajectory()
    title = f"{m.get('name')} (seed {m.get('seed')})"
    if len(t_s) > 1:

        def behaviour():
            world = world_of(config)
            body = rec.descriptions().get("body")
            summary["behaviour"] = behaviour_metrics(t_s, poses, world, body)
            for suffix in (".png", ".svg") if world is not None else ():
                figure = trajectory_figure(world, t_s, poses, title=title)
                path = save_figure(figure, run_dir / f"trajectory{suffix}", **TRAJECTORY_SAVE)
                summary["figures"].append(path.name)

        attempt("behaviour and trajectory", behaviour)
    channel, t_ms = rec.spikes()  # in time order
    summary["spikes"] = int(channel.size)
    if channel.size:

        def raster():
            culture = rec.descriptions().get("culture")
            cell_type = culture.cell_type if culture is not None else None
            paths = plot_raster(
                channel, t_ms, run_dir / "raster", cell_type, recorded_network_bursts(rec)
            )
            summary["figures"] += [Path(p).name for p in paths]

        attempt("raster", raster)
    summary["stimulation_pulses"] = _pulse_count(rec)
    write_whole(run_dir / SUMMARY_FILE, json.dumps(summary, indent=2))
    if summary["failures"]:
        write_manifest(run_dir, {**m, "postrun_failures": summary["failures"]})
    return summary


def recorded_network_bursts(rec) -> NetworkBursts | None:
    """The network bursts the burst observer reported during the run
    (:meth:`~hub.record.RunRecord.network_bursts`); None when none was reported."""
    rows = rec.network_bursts()
    if not rows:
        return None
    return NetworkBursts(
        **{
            key: np.array([row[key] for row in rows], np.float64)
            for key in ("start_ms", "end_ms", "core_start_ms", "core_end_ms")
        }
    )


def _pulse_count(rec) -> int:
    return sum(s.n_pulses for s in rec.decoded(Stimulation, "tx"))
