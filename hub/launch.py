"""Making endpoints from a config, and running them as local processes.

An endpoint's ``kind`` in the experiment file is either a registered short name
(``sim_robot``, ``sim_network``, ``nest``, ``khepera``, ``mea``) or ``module:Class``. The class
provides ``from_config(section, cfg) -> Endpoint`` and may provide
``check_config(section, cfg) -> dict``: a classmethod that checks the section's ``params``
without building anything (no network, no device connection), raising
:class:`~hub.config.ConfigError` naming ``<role>.params.<key>``, and returns the params
resolved (files read, contents in place) as the run will use them. ``neuvision run``
calls it for every endpoint before a run folder or a process exists, and records the
resolved params in the manifest (:func:`resolve_endpoints`).

Local endpoints are started with ``subprocess`` (fork-and-exec, before the hub
opens its own Zenoh session: a process that has a session must never fork).
"""

from __future__ import annotations

import ctypes
import dataclasses
import hashlib
import importlib
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from hub.config import BusSection, ConfigError, EndpointSection, ExperimentConfig
from hub.endpoint import Endpoint
from hub.scheduling import available_cpus

_PR_SET_PDEATHSIG = 1

ENDPOINT_KINDS = {
    "sim_robot": "sim_robot.endpoint:ArenaEndpoint",
    "sim_network": "sim_network.endpoint:NetworkEndpoint",
    "nest": "sim_network.endpoint:NestEndpoint",
    "khepera": "adapters.khepera.endpoint:KheperaEndpoint",
    "mea": "adapters.mea.endpoint:MeaEndpoint",
}

#: ``neuvision`` as a child process of this Python. ``-P``: the folder it is started in is
#: not put first on its import path (as ``-m`` alone would), so a folder holding another
#: copy of NeuVision cannot mix its modules with the installed ones; the command adds that
#: folder last itself, for a user's own schemes and endpoint kinds (hub/cli.py).
NEUVISION = (sys.executable, "-P", "-m", "hub.cli")


def endpoint_class(role: str, kind: str) -> type[Endpoint]:
    """The endpoint class for ``<role>.kind``, imported.

    Parameters
    ----------
    role : str
        ``"body"`` or ``"culture"``: the class must serve that role.
    kind : str
        A short name of :data:`ENDPOINT_KINDS` or ``module:Class``.

    Raises
    ------
    ConfigError
        Naming ``<role>.kind``: not of that form, not importable, or not an endpoint of
        ``role``.
    """
    spec = ENDPOINT_KINDS.get(kind, kind)
    module_name, sep, attr = spec.partition(":")
    if not sep:
        known = ", ".join(ENDPOINT_KINDS)
        raise ConfigError(f"{role}.kind must be one of {known} or module:Class, got {kind!r}")
    try:
        cls = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"{role}.kind: cannot load {spec!r}: {exc}") from None
    if not (isinstance(cls, type) and issubclass(cls, Endpoint)) or cls.role != role:
        raise ConfigError(f"{role}.kind: {spec} is not a {role} endpoint")
    return cls


def check_endpoint(cls: type[Endpoint], section: EndpointSection, cfg: ExperimentConfig) -> dict:
    """The section's params checked by the class's ``check_config`` and resolved.

    A class without ``check_config`` has its params returned as given (its
    ``from_config`` checks them when the endpoint starts), except that a class keeping the
    base ``from_config`` takes no parameters at all.

    Parameters
    ----------
    cls : type of Endpoint
        The section's class (:func:`endpoint_class`).
    section : EndpointSection
        The endpoint's section of the experiment.
    cfg : ExperimentConfig
        The whole experiment, for checks that need more than the section.

    Raises
    ------
    ConfigError
        Naming ``<role>.params.<key>``.
    """
    check = getattr(cls, "check_config", None)
    if check is not None:
        params = check(section, cfg)
        return dict(section.params) if params is None else params
    if cls.from_config.__func__ is Endpoint.from_config.__func__ and section.params:
        raise ConfigError(
            f"{cls.role}.params: {cls.__name__} takes no parameters, got {sorted(section.params)}"
        )
    return dict(section.params)


def resolve_endpoints(cfg: ExperimentConfig, local_only: bool = False) -> ExperimentConfig:
    """``cfg`` with each endpoint's params checked and resolved by its kind.

    Every ``launch = "local"`` endpoint's kind must load here. An external endpoint's is
    checked when its class loads on this machine (a device's package may live only where
    the device is); otherwise its params are kept as given (``local_only`` skips external
    endpoints altogether).

    Parameters
    ----------
    cfg : ExperimentConfig
        The experiment as loaded.
    local_only : bool
        Leave external endpoints' sections out of the check (kept as given).

    Raises
    ------
    ConfigError
        Naming ``<role>.kind`` or ``<role>.params.<key>``: before anything starts.
    """
    sections = {}
    for role in ("body", "culture"):
        section = cfg.endpoint(role)
        if section.launch == "local":
            cls = endpoint_class(role, section.kind)
        elif local_only:
            continue
        else:
            try:
                cls = endpoint_class(role, section.kind)
            except ConfigError:
                continue
        params = check_endpoint(cls, section, cfg)
        sections[role] = dataclasses.replace(section, params=params)
    return dataclasses.replace(cfg, **sections)


def _served(cfg: ExperimentConfig, role: str) -> dict | None:
    """``role``'s kind and params as its kind resolves them; None when the kind does not
    load here or its params do not check."""
    section = cfg.endpoint(role)
    try:
        params = check_endpoint(endpoint_class(role, section.kind), section, cfg)
    except ConfigError:
        return None
    return {"kind": section.kind, "params": params}


def _digest(value) -> str:
    text = json.dumps(value, sort_keys=True, separators=(",", ":"), default=repr)
    return hashlib.sha256(text.encode()).hexdigest()


def settings_digest(cfg: ExperimentConfig, role: str) -> str | None:
    """SHA-256 (hex) of ``role``'s kind and params as its kind resolves them: what an
    endpoint serves, compared by the hub with its own (an endpoint started with another
    experiment file, other ``--set`` items or another seed is refused before the run).
    Resolving is idempotent, so a hub's resolved config gives the digest of the files it was
    made from. None when the kind does not load here or its params do not check.

    Parameters
    ----------
    cfg : ExperimentConfig
        The experiment, resolved or not.
    role : str
        ``"body"`` or ``"culture"``.
    """
    served = _served(cfg, role)
    return None if served is None else _digest(served)


def settings_digests(cfg: ExperimentConfig, role: str) -> dict[str, str] | None:
    """A short digest of each setting ``role`` serves, by dotted key (``culture.kind``,
    ``culture.params.config.noise.sd``, ...): when :func:`settings_digest` differs, the hub
    names the settings that do, without the values crossing the bus.

    Parameters
    ----------
    cfg : ExperimentConfig
        The experiment, resolved or not.
    role : str
        ``"body"`` or ``"culture"``.
    """
    served = _served(cfg, role)
    if served is None:
        return None
    leaves: dict[str, str] = {}

    def walk(prefix: str, value) -> None:
        if isinstance(value, dict) and value:
            for key, item in value.items():
                walk(f"{prefix}.{key}", item)
        else:
            leaves[prefix] = _digest(value)[:12]

    walk(role, served)
    return leaves


def make_endpoint(cfg: ExperimentConfig, role: str) -> Endpoint:
    """The endpoint of ``role`` built by its kind's ``from_config`` (not yet serving).

    Parameters
    ----------
    cfg : ExperimentConfig
        The experiment.
    role : str
        ``"body"`` or ``"culture"``.

    Raises
    ------
    ConfigError
        The kind does not load, or its ``from_config`` refuses the section.
    """
    section = cfg.endpoint(role)
    return endpoint_class(role, section.kind).from_config(section, cfg)


@dataclass
class LocalProcess:
    """A child process started by this module: its role (``body``, ``culture``,
    ``observer`` or ``dashboard``), its ``Popen`` and the log its output goes to (None:
    discarded)."""

    role: str
    popen: subprocess.Popen
    log_path: Path | None


def die_with_parent() -> None:
    """Ask the kernel to send this process SIGTERM when its parent dies, even by SIGKILL
    (``PR_SET_PDEATHSIG``; Linux). Runs in a child between fork and exec.

    The kernel's "parent" is the thread that started the child: start endpoints from a
    thread that lives as long as they should (the main thread), or they end with it."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):
        pass


def start_local_endpoints(
    config_path: str | None, overrides: list[str], cfg: ExperimentConfig, log_dir: Path | None
) -> list[LocalProcess]:
    """Start every ``launch = "local"`` endpoint as ``neuvision endpoint ROLE``, a child
    that ends with this process (call from the main thread, before opening a Zenoh
    session: see :func:`die_with_parent` and the module docstring).

    Parameters
    ----------
    config_path : str or None
        The experiment file the children read.
    overrides : list of str
        The ``--set`` items they are given, as the runner was.
    cfg : ExperimentConfig
        The experiment, which says which endpoints are local.
    log_dir : Path or None
        Where each writes ``<role>.log``; None discards their output.

    Raises
    ------
    ConfigError
        A local endpoint's kind does not load (checked before any child starts).
    """
    procs = []
    for role in ("body", "culture"):
        if cfg.endpoint(role).launch != "local":
            continue
        endpoint_class(role, cfg.endpoint(role).kind)  # fail here, not in the child
        cmd = ["endpoint", role]
        procs.append(_start_local(role, cmd, config_path, overrides, log_dir))
    return procs


def start_burst_observer(
    bus: BusSection, log_dir: Path | None, hub_cpus: Sequence[int] = ()
) -> LocalProcess:
    """Start ``neuvision observe bursts --once`` on the hub's bus, off the CPUs kept for the
    hub (``loop.cpus``) where others are left. The hub starts it for a run with
    ``online.launch = "local"``.

    Parameters
    ----------
    bus : BusSection
        The hub's bus; the observer connects where the hub listens, unless
        ``bus.connect`` says where.
    log_dir : Path or None
        Where it writes ``observer.log``; None discards its output.
    hub_cpus : sequence of int
        The CPUs kept for the hub; empty: no affinity is set.
    """
    overrides = [f"bus.{k}={json.dumps(v)}" for k, v in dataclasses.asdict(bus).items()]
    # It reaches the hub where the hub listens (a wildcard address: on this machine).
    connect = [re.sub(r"/(0\.0\.0\.0|\[::\]):", "/127.0.0.1:", a) for a in bus.listen]
    overrides.append(f"bus.connect={json.dumps(bus.connect or connect)}")
    available = available_cpus() if hub_cpus else None
    others = available - set(hub_cpus) if available else set()
    command = ["observe", "bursts", "--once"]
    return _start_local("observer", command, None, overrides, log_dir, cpus=others)


def _start_local(
    role: str,
    command: list[str],
    config_path: str | None,
    overrides: list[str],
    log_dir,
    cpus: set[int] | None = None,
) -> LocalProcess:
    """``neuvision COMMAND [CONFIG] --set ...`` as a child that ends with its runner (on
    ``cpus`` if given)."""

    def child() -> None:
        die_with_parent()
        if cpus:
            os.sched_setaffinity(0, cpus)

    cmd = [*NEUVISION, *command]
    if config_path:
        cmd.append(str(config_path))
    for item in overrides:
        cmd += ["--set", item]
    log_path = log_dir / f"{role}.log" if log_dir else None
    out = open(log_path, "wb") if log_path else subprocess.DEVNULL
    try:
        popen = subprocess.Popen(
            cmd,
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=subprocess.STDOUT,
            # Ctrl-C, or the terminal closing, goes to the runner, which stops us in order
            start_new_session=True,
            # A runner killed outright: its endpoints end too (a body stops its motors).
            preexec_fn=child,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
    finally:
        if log_path:
            out.close()
    return LocalProcess(role, popen, log_path)


def dashboard_address(cfg: ExperimentConfig) -> tuple[str, int]:
    """Where a run's local dashboard will serve: ``dashboard.host`` and ``dashboard.port``,
    a free port when it is 0.

    Raises
    ------
    ConfigError
        The port is taken (another dashboard?): before anything starts.
    """
    import socket

    host, port = cfg.dashboard.host, cfg.dashboard.port
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, port))
        except OSError as exc:
            raise ConfigError(
                f"dashboard.port: cannot serve on {host}:{port} ({exc.strerror or exc}; "
                "another dashboard?); --set dashboard.port=0 picks a free one"
            ) from None
        return host, sock.getsockname()[1]


def start_local_dashboard(
    config_path: str | None, overrides: list[str], port: int, log_dir: Path | None
) -> LocalProcess:
    """Start ``neuvision dashboard`` on the run's bus, serving on ``port``; it ends with its
    runner (like the endpoints, started before the hub opens its session).

    Parameters
    ----------
    config_path : str or None
        The experiment file it reads.
    overrides : list of str
        The ``--set`` items it is given.
    port : int
        Where it serves (:func:`dashboard_address`).
    log_dir : Path or None
        Where it writes ``dashboard.log``; None discards its output.
    """
    command = ["dashboard", "--port", str(port)]
    return _start_local("dashboard", command, config_path, overrides, log_dir)


def stop_local_endpoints(procs: list[LocalProcess], timeout_s: float = 10.0) -> dict[str, int]:
    """SIGTERM each, wait, SIGKILL what is left; return the exit codes by role.

    Parameters
    ----------
    procs : list of LocalProcess
        The children to stop (those already ended just give their code).
    timeout_s : float
        How long all of them together have to end before SIGKILL.
    """
    for p in procs:
        if p.popen.poll() is None:
            p.popen.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + timeout_s
    codes = {}
    for p in procs:
        try:
            codes[p.role] = p.popen.wait(timeout=max(deadline - time.monotonic(), 0.1))
        except subprocess.TimeoutExpired:
            p.popen.kill()
            codes[p.role] = p.popen.wait()
    return codes


def watch_local_endpoints(procs: list[LocalProcess], on_exit) -> threading.Event:
    """Call ``on_exit(message)`` once if a local endpoint process ends on its own.

    Parameters
    ----------
    procs : list of LocalProcess
        The children to watch (polled every 0.1 s from a daemon thread).
    on_exit : callable
        Called from that thread with one line: which ended, its status and its log's last
        line.

    Returns
    -------
    threading.Event
        Set it to stop watching (before stopping the processes).
    """
    done = threading.Event()

    def watch():
        while not done.wait(0.1):
            for p in procs:
                code = p.popen.poll()
                if code is not None:
                    on_exit(f"{p.role} endpoint exited with status {code}{last_line(p.log_path)}")
                    return

    threading.Thread(target=watch, name="endpoint-watch", daemon=True).start()
    return done


def last_line(path: Path | None) -> str:
    """': <the last line of a child's log>', or '' (no log, an empty one)."""
    if path is None or not path.exists():
        return ""
    lines = [ln for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    return f": {lines[-1].strip()}" if lines else ""
