"""Experiments from Python: load a file, change keys, run, and get arrays back.

The same run as ``neuvision run`` (the hub in this process, each local endpoint a process
of its own, everything recorded and summarised), for notebooks and scripts::

    from neuvision import Experiment

    exp = Experiment("configs/closed_loop.toml", {"experiment.duration_s": 5})
    exp.set("experiment.seed", 3)
    run = exp.run(runs_dir="runs")
    channel, t_ms = run.spikes
    t_s, poses = run.trajectory
    run.summary["behaviour"]["distance_m"]

A coding or decoding scheme may be a plain function of the caller's
(``exp.use_coding(my_coder, gain=2.0)``): the hub runs in this process and imports it
from its module, ``__main__`` included. :meth:`Run.open` reads any run folder.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import signal
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hub import stopping
from hub.config import ConfigError, ExperimentConfig, load_config
from hub.protocol import MotorCommand, SensorReading, Stimulation
from hub.record import MANIFEST_FILE, RunRecord, read_manifest, read_run, write_manifest
from settings.overrides import format_value

log = logging.getLogger(__name__)


def run_experiment(
    config: str | Path | None,
    overrides: list[str],
    *,
    local: bool = True,
    progress=None,
    announce: Callable[[str], None] = lambda line: None,
    install_signals: bool = True,
    dashboard: bool = False,
):
    """Run one experiment: check it, start its local endpoints, run the hub, summarise.

    What ``neuvision run`` (``local``) and ``neuvision hub`` do. Every key is checked
    before a folder or a process exists.

    Parameters
    ----------
    config : path or None
        The experiment file (None: the defaults).
    overrides : list of str
        ``key=value`` items, as ``--set`` takes them.
    local : bool
        Start the ``launch = "local"`` endpoints (else they are started elsewhere).
    progress : optional
        The hub's progress display (``hub.cli.ProgressBar``).
    announce : callable
        Called with each line a user should see (the run folder, endpoint exits).
    install_signals : bool
        SIGINT/SIGTERM end the run as ``interrupted`` (main thread only).
    dashboard : bool
        Also serve the live dashboard (``[dashboard]``) for the run's length, as a process
        of its own watching the run's bus (``neuvision run --dashboard``).

    Returns
    -------
    hub.loop.RunResult

    Raises
    ------
    ConfigError
        Naming the key, before anything starts.
    """
    from hub.bus import free_tcp_port
    from hub.launch import (
        dashboard_address,
        last_line,
        start_local_dashboard,
        start_local_endpoints,
        stop_local_endpoints,
        watch_local_endpoints,
    )
    from hub.loop import Hub
    from hub.record import new_run_dir
    from hub.scheduling import check_cpus
    from lab.postrun import after_run

    overrides = list(overrides)
    cfg = load_config(config, overrides)
    port = None
    if local and all(cfg.endpoint(r).launch == "local" for r in ("body", "culture")):
        # Everything on this machine: a free loopback port keeps parallel runs apart.
        scheme = "tcp" if cfg.bus.security == "none" else "tls"
        port = free_tcp_port()
        overrides.append(f'bus.listen=["{scheme}/127.0.0.1:{port}"]')
        cfg = load_config(config, overrides)
    check_cpus("loop.cpus", cfg.loop.cpus)
    for role in ("body", "culture"):
        if local and cfg.endpoint(role).launch == "local":
            check_cpus(f"{role}.cpus", cfg.endpoint(role).cpus)
    # Every endpoint's kind and params are checked here, before a folder or a process
    # exists; the manifest records them resolved (culture and world contents included).
    cfg = cfg.resolved()
    check_hub_sections(cfg)
    started_here = ["hub"] + [
        r for r in ("body", "culture") if local and cfg.endpoint(r).launch == "local"
    ]
    if cfg.online.enabled and cfg.online.launch == "local":
        started_here.append("observer")  # the hub starts it
    from hub.bus import check_security_files  # Zenoh: only where a run starts

    check_security_files(cfg.bus, started_here)
    dash_host, dash_port = dashboard_address(cfg) if dashboard else (None, None)
    run_dir = new_run_dir(cfg.experiment.runs_dir, cfg.experiment.name)
    announce(f"run folder {run_dir}")
    awaited = [r for r in ("body", "culture") if cfg.endpoint(r).launch == "local"]
    if not local and awaited:  # `neuvision hub` on a file whose endpoints are "local"
        where = ", ".join(cfg.bus.listen)
        announce(
            "the hub starts no endpoint: start "
            + " and ".join(f"'neuvision endpoint {r} CONFIG --connect HOST'" for r in awaited)
            + f" (the hub listens on {where}), or give 'neuvision run' to start them here"
        )
    procs = start_local_endpoints(config, overrides, cfg, run_dir) if local else []
    dash = None
    if dashboard:
        dash = start_local_dashboard(config, overrides, dash_port, run_dir)
        shown = "127.0.0.1" if dash_host in ("0.0.0.0", "::") else dash_host
        announce(f"dashboard at http://{shown}:{dash_port}/ for the run's length")
    wait_s = cfg.dashboard.wait_s if dash is not None else 0.0
    hub = Hub(cfg, run_dir=run_dir, progress=progress, wait_for_view_s=wait_s)
    signals = install_signals and threading.current_thread() is threading.main_thread()
    if signals:

        def hung_up(*_) -> None:  # the terminal closed: say nothing more on it
            stopping.quiet_terminal()
            hub.request_stop("interrupted")

        previous = {
            sig: signal.signal(sig, lambda *_: hub.request_stop("interrupted"))
            for sig in (signal.SIGINT, signal.SIGTERM)
        }
        previous[signal.SIGHUP] = signal.signal(signal.SIGHUP, hung_up)
        if stopping.signalled_while_starting():  # and its KeyboardInterrupt was lost
            hub.request_stop("interrupted")
    watching = watch_local_endpoints(procs, hub.request_stop)
    with _said_where(cfg, port, run_dir, announce):
        try:
            result = hub.run()
        finally:
            watching.set()
            if signals:
                for sig, handler in previous.items():
                    signal.signal(sig, handler)
            if progress is not None:
                progress.close()
            codes = stop_local_endpoints(procs)
            if dash is not None:
                ended_early = dash.popen.poll()
                stop_local_endpoints([dash])
                if ended_early:
                    announce(
                        f"the dashboard ended early (status {ended_early}); see {dash.log_path}"
                    )
    logs = {p.role: p.log_path for p in procs}
    exits = {}
    for role, code in codes.items():
        if code == -signal.SIGTERM:  # stopped above while still starting, before its handler
            log.debug("%s endpoint stopped while it was starting up", role)
        elif code != 0:  # its own last word: the cause the hub saw only as its vanishing
            said = last_line(logs[role])
            announce(f"{role} endpoint exited with status {code}{said}")
            exits[role] = {"status": code, "last_line": said.removeprefix(": ")}
    if exits:  # in the run's record too, beside the hub's reason ("body/0 died at step 61")
        _note_in_manifest(result.run_dir, "local_endpoint_exits", exits)
    if result.outcome != "fault" or result.steps > 0:  # a fault after steps: what it recorded
        try:
            summary = after_run(result, cfg)
        except Exception as exc:  # the run is recorded whatever its summary does
            if not isinstance(exc, OSError):  # a full disk needs no traceback; a bug does
                log.exception("the summary of %s failed", result.run_dir)
            announce(f"the run's summary failed ({type(exc).__name__}: {exc}); its record is whole")
        else:
            for failure in summary.get("failures", []):
                announce(f"summary: {failure['part']} failed: {failure['error']}")
    return result


def _note_in_manifest(run_dir: Path, key: str, value) -> None:
    """Add ``key`` to a finished run's manifest (what its runner learnt after the hub)."""
    try:
        manifest = json.loads((run_dir / MANIFEST_FILE).read_text())
        manifest[key] = value
        write_manifest(run_dir, manifest)
    except (OSError, ValueError) as exc:
        log.warning("could not add %s to %s's manifest: %s", key, run_dir, exc)


def _said_where(cfg: ExperimentConfig, port: int | None, run_dir: Path, announce):
    """A hub says where it listens, while it runs, to ``neuvision ctl`` and ``neuvision
    dashboard`` on this machine (found by session alone); one on a port of its own
    (``port``: ``neuvision run``'s) says it to the user too."""
    from hub.local_hubs import announced, reachable_here

    session = cfg.bus.session
    if port is not None:
        announce(
            f"the hub listens on 127.0.0.1:{port}, session {session!r} (neuvision ctl "
            f"status|pause|resume|stop --session {session}; neuvision dashboard likewise)"
        )
    return announced(session, [reachable_here(loc) for loc in cfg.bus.listen], run_dir)


def check_hub_sections(cfg: ExperimentConfig) -> None:
    """What the hub can check of its own sections before the endpoints describe
    themselves: the schemes import and their params pass the checks that need no
    description (:func:`hub.schemes.check_scheme`), the online detectors' parameters are
    valid. Raises :class:`ConfigError` naming the key."""
    from hub.analysis.bursts import BurstParams
    from hub.analysis.network_bursts import NetworkBurstParams
    from hub.schemes import check_scheme

    for name in ("coding", "decoding"):
        section = getattr(cfg, name)
        check_scheme(name, section.scheme, section.params, cfg.loop.period_ms, cfg.experiment.seed)
    if cfg.online.enabled:
        for name, kind in (("burst", BurstParams), ("network", NetworkBurstParams)):
            given = getattr(cfg.online, name)
            known = [f.name for f in dataclasses.fields(kind)]
            unknown = sorted(set(given) - set(known))
            if unknown:
                raise ConfigError(
                    f"online.{name}.{unknown[0]} is not a known key (known: {', '.join(known)})"
                )
            try:
                kind(**given)
            except (TypeError, ValueError) as exc:
                # the analysis names its own tables ("bursts.window_ms ..."): said as here
                why = str(exc)
                for own in ("bursts.", "network_bursts."):
                    if why.startswith(own):
                        raise ConfigError(f"online.{name}.{why.removeprefix(own)}") from None
                raise ConfigError(f"online.{name}: {why}") from None


@dataclass
class Experiment:
    """An experiment file with changes, ready to run.

    Parameters
    ----------
    config : path, optional
        The experiment file (TOML); None: the defaults (the simulated culture and robot,
        with no coding and no decoding: nothing stimulated, the robot still; the paper's
        closed loop is ``configs/closed_loop.toml``).
    overrides : dict, optional
        ``{"dotted.key": value}`` changes, checked at once.

    Raises
    ------
    ConfigError
        A bad file or key: the message names it.
    """

    config: str | Path | None = None
    overrides: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        if self.config is not None and not isinstance(self.config, str | os.PathLike):
            raise ConfigError(
                f"config must be an experiment file's path (or None), got {self.config!r}"
            )
        if not isinstance(self.overrides, Mapping):
            raise ConfigError(f"overrides must be a dict of dotted keys, got {self.overrides!r}")
        self.overrides = dict(self.overrides)
        self._check()  # now, not at run time

    @property
    def cfg(self) -> ExperimentConfig:
        """The experiment as it would run (its keys validated)."""
        return load_config(self.config, self._items())

    def _check(self) -> None:
        """Every check ``neuvision run`` makes before a run folder exists: the keys, each
        endpoint's kind and parameters (culture and world files read), the schemes' and the
        live analysis's parameters."""
        cfg = self.cfg.resolved()
        check_hub_sections(cfg)

    def set(self, key: str, value) -> Experiment:
        """Change one key, checked now as ``neuvision run`` checks it; returns self.

        Parameters
        ----------
        key : str
            Dotted (``"loop.period_ms"``, ``"culture.params.config"``).
        value : Any
            A TOML value: number, bool, string, path, list or table of them.

        Raises
        ------
        ConfigError
            The key or value is refused; the experiment is left as it was.
        """
        return self._set({key: value})

    def _set(self, items: dict) -> Experiment:
        before = dict(self.overrides)
        self.overrides.update(items)
        try:
            self._check()
        except ConfigError:
            self.overrides = before
            raise
        return self

    def use_coding(self, scheme: Callable | str, **params) -> Experiment:
        """Code sensors into stimulation with ``scheme`` (a function or ``module:name``)."""
        return self._use("coding", scheme, params)

    def use_decoding(self, scheme: Callable | str, **params) -> Experiment:
        """Decode spikes into motion with ``scheme`` (a function or ``module:name``)."""
        return self._use("decoding", scheme, params)

    def _use(self, section: str, scheme, params: dict) -> Experiment:
        if callable(scheme):
            scheme = f"{scheme.__module__}:{scheme.__qualname__}"
        return self._set({f"{section}.scheme": scheme, f"{section}.params": params})

    def _items(self) -> list[str]:
        return [f"{k}={format_value(v)}" for k, v in self.overrides.items()]

    def run(self, runs_dir: str | Path | None = None, *, progress: bool = False) -> Run:
        """Run it (the mode is the file's ``loop.mode``) and return the recorded run.

        A scheme given as a function of ``__main__`` runs in the hub's process (this one);
        the endpoints are processes of their own. Blocks until the run ends.

        Parameters
        ----------
        runs_dir : path, optional
            Where the run's folder is made (default ``experiment.runs_dir``).
        progress : bool
            Show the progress bar on stderr.

        Raises
        ------
        RuntimeError
            The run left no record (it ended before its folder was made).
        """
        items = self._items()
        if runs_dir is not None:
            items.append(f"experiment.runs_dir={format_value(str(runs_dir))}")
        bar = None
        if progress:
            from hub.cli import ProgressBar

            bar = ProgressBar()
        result = run_experiment(
            self.config, items, progress=bar, announce=lambda line: log.info("%s", line)
        )
        if result.run_dir is None:
            raise RuntimeError(f"the run left no record ({result.outcome}: {result.reason})")
        return Run.open(result.run_dir)


class Run:
    """A recorded run, as arrays (times in the run's time).

    Parameters
    ----------
    run_dir : path
        A run folder (``manifest.json`` and ``record.nvrec``).
    """

    def __init__(self, run_dir: str | Path):
        self.run_dir = Path(run_dir)
        if not (self.run_dir / MANIFEST_FILE).is_file():
            raise FileNotFoundError(f"{self.run_dir} is not a run folder (no {MANIFEST_FILE})")
        self._record: RunRecord | None = None
        self._manifest: dict | None = None

    @classmethod
    def open(cls, run_dir: str | Path) -> Run:
        """The run in ``run_dir`` (as ``Run(run_dir)``); FileNotFoundError if not a run folder."""
        return cls(run_dir)

    def __repr__(self) -> str:
        return f"Run({str(self.run_dir)!r}, outcome={self.outcome!r}, steps={self.steps})"

    @property
    def record(self) -> RunRecord:
        """The whole record (every message and event): :class:`hub.record.RunRecord`."""
        if self._record is None:
            self._record = read_run(self.run_dir)
        return self._record

    @property
    def manifest(self) -> dict:
        """``manifest.json``: the run's config, seed, hosts, start, end, outcome, timing
        (read on its own: the record, which may be GBs, is read only when asked for)."""
        if self._record is not None:
            return self._record.manifest
        if self._manifest is None:
            self._manifest = read_manifest(self.run_dir)
        return self._manifest

    @property
    def outcome(self) -> str:
        """How the run ended, as its manifest says ("" if it says nothing)."""
        return self.manifest.get("outcome", "")

    @property
    def steps(self) -> int:
        """The steps the run made, as its manifest says (0 if it says nothing)."""
        return int(self.manifest.get("steps") or 0)

    @property
    def summary(self) -> dict:
        """``summary.json`` (empty if the run has none: a run that faulted before its first
        step)."""
        path = self.run_dir / "summary.json"
        return json.loads(path.read_text()) if path.is_file() else {}

    @property
    def spikes(self) -> tuple[np.ndarray, np.ndarray]:
        """``(channel, t_ms)`` of every recorded spike, in time order."""
        return self.record.spikes()

    @property
    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """``(t_s[n], pose[n, 3])``: the body's poses (x_m, y_m, heading_rad), in step order."""
        return self.record.trajectory()

    @property
    def sensors(self) -> tuple[np.ndarray, np.ndarray]:
        """``(t_s[n], ranges_m[n, sensors])``: the body's range readings, in time order."""
        readings = sorted(self.record.decoded(SensorReading, "rx", "late"), key=_by_step)
        t_s = np.array([r.t_s for r in readings], dtype=np.float64)
        n = readings[0].ranges_m.size if readings else 0
        return t_s, np.array([r.ranges_m for r in readings], dtype=np.float64).reshape(-1, n)

    @property
    def motor(self) -> tuple[np.ndarray, np.ndarray]:
        """``(t_s[n], wheels_mps[n, 2])``: the wheel speeds sent, from each step's start."""
        commands = sorted(self.record.decoded(MotorCommand, "tx"), key=_by_step)
        t_s = np.array([m.t0_s for m in commands], dtype=np.float64)
        wheels = np.array([(m.left_mps, m.right_mps) for m in commands], dtype=np.float64)
        return t_s, wheels.reshape(-1, 2)

    @property
    def stimulation(self) -> dict[str, np.ndarray]:
        """Every pulse sent: ``t_ms`` (onset, run time), ``channel``, ``amplitude_ua``,
        ``width_ms``; in time order."""
        stims = self.record.decoded(Stimulation, "tx")
        parts = {"t_ms": [], "channel": [], "amplitude_ua": [], "width_ms": []}
        for s in stims:
            parts["t_ms"].append(s.t0_s * 1e3 + np.asarray(s.onset_ms, dtype=np.float64))
            parts["channel"].append(np.asarray(s.channel))
            parts["amplitude_ua"].append(np.asarray(s.amplitude_ua, dtype=np.float64))
            parts["width_ms"].append(np.asarray(s.width_ms, dtype=np.float64))
        out = {k: np.concatenate(v) if v else np.zeros(0) for k, v in parts.items()}
        order = np.argsort(out["t_ms"], kind="stable")
        return {k: v[order] for k, v in out.items()}


def _by_step(message) -> int:
    return message.step
