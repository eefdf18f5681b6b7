"""A run's manifest (``manifest.json`` in its folder): what ran, and how it ended.

It is written as the run begins (the config as resolved and its file's text, the
versions, the hosts; outcome ``running``) and again at its end, whatever ended it (the
outcome and why, the steps, the loop's timing and counts, the endpoints, the rejoins).
The run's record (:class:`~hub.record.Recorder`, ``record.enabled``) is opened and closed
with it. Reading both back is :func:`hub.record.read_run`'s.
"""

from __future__ import annotations

import logging
from pathlib import Path

from hub.config import ExperimentConfig
from hub.record import (
    Recorder,
    RecordError,
    experiment_text,
    host,
    utc_now,
    versions,
    write_manifest,
)

log = logging.getLogger(__name__)


class RunManifest:
    """The manifest of one run, and its record opened and closed with it.

    Parameters
    ----------
    cfg : ExperimentConfig
        The run's experiment, as resolved (what the manifest records).
    run_id : str
    run_dir : Path or None
        The run's folder (None: no manifest, no record).

    Attributes
    ----------
    fields : dict
        What the manifest says so far.
    """

    def __init__(self, cfg: ExperimentConfig, run_id: str, run_dir: Path | None):
        self.cfg, self.run_dir = cfg, run_dir
        self.fields = {
            "format": "neuvision-run",
            "v": 1,
            "name": cfg.experiment.name,
            "seed": cfg.experiment.seed,
            "run_id": run_id,
            "config_source": cfg.source,
            "config_text": experiment_text(cfg.source),
            "config": cfg.to_dict(),
            "versions": versions(),
            "hosts": {"hub": host()},
            "start_utc": utc_now(),
            "outcome": "running",
        }

    def begin(self) -> Recorder | None:
        """Write the manifest with the outcome ``running`` and open the run's record (with
        ``record.enabled``; without, the manifest only): the recorder, or None.

        Raises
        ------
        OSError
            The folder cannot be written.
        """
        if not self.run_dir:
            return None
        recorder = None
        if self.cfg.record.enabled:
            recorder = Recorder(self.run_dir, flush_s=self.cfg.record.flush_s)
        write_manifest(self.run_dir, self.fields)
        return recorder

    def close(self, recorder: Recorder | None, outcome: str, reason: str, **results) -> str:
        """The run's end in its record (an ``end`` event; the record closed) and its
        manifest, whatever ended it.

        Parameters
        ----------
        recorder : Recorder or None
            The run's record (None: not recorded).
        outcome, reason : str
            How the run ended, and why.
        **results
            The rest of the manifest's end (timing, counts, rejoins, ...).

        Returns
        -------
        str
            What could not be written (a full disk, the run folder gone), said in the log;
            ``""`` when all was.
        """
        failed = []
        if recorder:
            try:
                recorder.event("end", outcome=outcome, reason=reason)
                recorder.close()
            except RecordError as exc:
                failed.append(str(exc))
        if self.run_dir:
            self.fields.update(end_utc=utc_now(), outcome=outcome, reason=reason, **results)
            try:
                write_manifest(self.run_dir, self.fields)
            except OSError as exc:
                failed.append(f"its manifest could not be written to {self.run_dir}: {exc}")
        if not failed:
            return ""
        why = "the run's record could not be closed: " + "; ".join(failed)
        log.error("%s", why)
        return why
