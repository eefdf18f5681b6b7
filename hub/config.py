"""Experiment configuration: the experiment file's sections, defaults and limits.

The defaults of every hub-level setting live in the dataclasses below and nowhere else.
:func:`load_config` reads an experiment file through :mod:`settings` (the project's one
loader: TOML only, ``extends``, paths relative to the file, ``key=value`` overrides) and
validates every key: unknown or invalid ones are reported by their dotted path
(``loop.period_ms must be >= 0.1, got 1e-06``).

Endpoint-specific settings (``body.params``, ``culture.params``) are free tables here; each
endpoint kind checks its own (``check_config``, see :mod:`hub.launch`), naming the same
dotted paths. In them, ``world``, ``config`` and any key ending in ``_file`` name files:
relative paths are taken from the folder of the file that names them
(:data:`PATH_KEYS`). ``experiment.runs_dir`` is where output goes and is taken from the
current folder, like any output path on a command line.
"""

from __future__ import annotations

import dataclasses
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import settings
from hub.protocol import MODES, Keys, key_chunk_problem
from hub.security import SECURITY_MODES
from settings import ConfigError, bounds

__all__ = [
    "MAX_STEPS",
    "PATH_KEYS",
    "BusSection",
    "ConfigError",
    "DashboardSection",
    "EndpointSection",
    "ExperimentConfig",
    "ExperimentSection",
    "LoopSection",
    "OnlineSection",
    "PolicySection",
    "RecordSection",
    "SchemeSection",
    "check_value",
    "from_dict",
    "load_config",
]

# Keys that name files, resolved relative to the file naming them (dotted patterns).
PATH_KEYS = ("*.params.world", "*.params.config", "*.params.*_file", "bus.certs_dir")
# The most steps a run may have (duration_s / period_ms): the hub keeps a few numbers per
# step (~16 bytes), and 10 million steps are 28 h at 10 ms.
MAX_STEPS = 10_000_000


def _cpus(dotted: str, value: Any) -> tuple[int, ...]:
    if not isinstance(value, list | tuple) or not all(
        isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in value
    ):
        raise ConfigError(f"{dotted} must be a list of CPU numbers (>= 0), got {value!r}")
    if len(set(value)) != len(value):
        raise ConfigError(f"{dotted} names a CPU twice: {value!r}")
    return tuple(value)


def _session(dotted: str, value: str) -> str:
    try:
        Keys(value)
    except ValueError as exc:
        raise ConfigError(f"{dotted}: {exc}") from None
    return value


def _key_chunk(dotted: str, value: str) -> str:
    problem = key_chunk_problem(value, "endpoint id")
    if problem:
        raise ConfigError(f"{dotted}: {problem}")
    return value


def _callable(dotted: str, value: str) -> str:
    if value.count(":") != 1:
        raise ConfigError(f"{dotted} must name a callable as module:function, got {value!r}")
    return value


# A run folder is named <UTC time>-<experiment.name>: the name must be one safe folder-name
# part (no separators, no "..", nothing a shell or another OS would trip on).
NAME_CHARS = "ASCII letters, digits, '_', '-' and '.' (not first)"
_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]{0,99}")


def _name(dotted: str, value: str) -> str:
    if not _NAME.fullmatch(value) or ".." in value:
        raise ConfigError(
            f"{dotted} must be 1 to 100 of {NAME_CHARS}, without '..' (it names the run "
            f"folder), got {value!r}"
        )
    return value


def _analysis(dotted: str, value: dict) -> dict:
    from hub.analysis.metrics import AnalysisParams  # numpy and numba: only when given

    try:
        AnalysisParams.from_dict(value)
    except ValueError as exc:  # AnalysisInputError, named analysis.<key>
        raise ConfigError(str(exc)) from None
    return value


CPUS = bounds(parse=_cpus)


@dataclass(frozen=True)
class ExperimentSection:
    """``[experiment]``: what the run is called, its seed and length, where runs go."""

    name: str = field(default="experiment", metadata=bounds(check=_name))
    # sent to the endpoints with the run (an unsigned 64-bit integer on the wire)
    seed: int = field(default=0, metadata=bounds(ge=0, le=2**64 - 1))
    duration_s: float = field(default=10.0, metadata=bounds(gt=0))
    runs_dir: str = "runs"
    notes: str = ""  # free text, kept in the manifest with the config


@dataclass(frozen=True)
class LoopSection:
    """``[loop]``: the hub's clock: the period, lockstep or realtime, the waits and
    deadlines, the CPUs and scheduling of the hub's threads (docs/architecture.md)."""

    # 0.1 ms (10 kHz) is faster than any loop can step; with duration_s it sets the steps
    # (at most MAX_STEPS).
    period_ms: float = field(default=10.0, metadata=bounds(ge=0.1, le=10_000))
    mode: str = field(default="lockstep", metadata=bounds(choices=MODES))
    # How long to wait for the required endpoints to appear before giving up (the hub says
    # every 5 s what it waits for). A first run in a fresh checkout compiles the simulators'
    # kernels, the culture's, the arena's and the observer's at once: over 30 s on a busy
    # 2-vCPU machine.
    wait_timeout_s: float = field(default=120.0, metadata=bounds(gt=0))
    # Lockstep: a reply not in after this long is counted missing (policy applies).
    reply_timeout_s: float = field(default=5.0, metadata=bounds(gt=0))
    # Realtime: a reply must arrive within this long after its step's start
    # (0 means one period: before the next step starts).
    deadline_ms: float = field(default=0.0, metadata=bounds(ge=0))
    status_hz: float = field(default=4.0, metadata=bounds(gt=0, le=100))
    # HubView for live displays (hub/view), this often while anyone subscribes (0: never).
    view_hz: float = field(default=30.0, metadata=bounds(ge=0, le=100))
    # At the end of every run the body is sent a stop; the hub waits this long for the
    # body's reply to it, the proof that it was applied (the manifest says which).
    final_stop_wait_s: float = field(default=0.5, metadata=bounds(ge=0, le=60))
    # Realtime: the SCHED_FIFO priority of the hub's threads during the steps (1-99; 0
    # leaves the scheduler alone). Refused without CAP_SYS_NICE/RLIMIT_RTPRIO: the run
    # goes on, and the manifest says so.
    realtime_priority: int = field(default=10, metadata=bounds(ge=0, le=99))
    # While the steps run, ask Linux's PM QoS to keep idle CPUs awake (a wake-up latency of
    # 0 µs): a message that wakes a thread on an idle CPU then does not wait for that CPU
    # to wake (hub/scheduling.py). Needs write access to /dev/cpu_dma_latency; without it
    # the run goes on, and the manifest says so. Costs the idle CPUs' power while it runs.
    keep_cpus_awake: bool = True
    # The CPUs the hub's process runs on (empty: wherever the OS puts it). A CPU of its
    # own keeps the hub's threads from waiting behind the endpoints' (docs/architecture.md, "CPU
    # placement"). Not for runs side by side: each would take the same CPUs.
    cpus: tuple[int, ...] = field(default=(), metadata=CPUS)

    @property
    def deadline_s(self) -> float:
        """The realtime reply deadline after a step's start, in s (``deadline_ms``, or one
        period when it is 0)."""
        return (self.deadline_ms or self.period_ms) / 1e3

    def late_window_problem(self) -> str:
        """Why a device that answers each window after it has passed (its reply comes
        during the next step) cannot take this realtime loop, or "" when it can: the
        deadline must lie between one and two periods."""
        period_ms = self.period_ms
        if self.mode != "realtime" or period_ms < self.deadline_s * 1e3 < 2 * period_ms:
            return ""
        return (
            f"loop.deadline_ms must lie between one and two periods ({period_ms:g} and "
            f"{2 * period_ms:g} ms; e.g. {1.8 * period_ms:g}): a device that answers each "
            "window after it has passed replies during the next step"
        )


@dataclass(frozen=True)
class PolicySection:
    """``[policy]``: what the hub does when an endpoint is late, silent or gone."""

    # What the hub codes when a body's sensor reading is late or missing.
    missing_sensors: str = field(
        default="zero_stim", metadata=bounds(choices=("zero_stim", "hold"))
    )
    # What the hub sends the body when a culture's spikes are late or missing.
    missing_spikes: str = field(
        default="stop_robot", metadata=bounds(choices=("stop_robot", "hold"))
    )
    # What happens when a required endpoint dies mid-run.
    endpoint_death: str = field(default="stop", metadata=bounds(choices=("stop", "continue")))
    # An endpoint whose liveliness vanishes may come back within this long (a restarted
    # process, a link that dropped) and rejoin the run; the gap is recorded. Beyond it,
    # `endpoint_death` applies. 0: a vanished endpoint is dead at once.
    rejoin_s: float = field(default=0.0, metadata=bounds(ge=0))
    # An endpoint that stays on the bus but answers none of its inputs, each stood in for
    # by the policy one after another for this long, is taken for dead (`endpoint_death`
    # applies): hung, or another process took its name on the bus. 0: never.
    silent_s: float = field(default=30.0, metadata=bounds(ge=0))


_IP_SCHEMES = ("tcp", "tls", "udp", "quic")


def _locator_problem(locator: str) -> str:
    """Why ``locator`` is not a Zenoh locator of an IP scheme (``tcp/HOST:PORT``, the
    port 0 to 65535; ``[IPv6]`` in brackets), or "" (other schemes are left to Zenoh)."""
    scheme, slash, rest = locator.partition("/")
    if not slash:
        return "is not an address: give tcp/HOST:PORT (or tls/HOST:PORT)"
    if scheme not in _IP_SCHEMES:
        return ""
    address = re.split(r"[?#]", rest, maxsplit=1)[0]  # Zenoh's options after ? or #
    host, colon, port = address.rpartition(":")
    if not colon or not host or host in ("[]",):
        return f"has no host and port: give {scheme}/HOST:PORT"
    if not (port.isdigit() and int(port) <= 65535):
        return f"has no port 0 to 65535 (got {port!r})"
    return ""


@dataclass(frozen=True)
class BusSection:
    """``[bus]``: the Zenoh session: its name, where the hub listens and participants
    connect, its security (docs/remote.md)."""

    session: str = field(default="default", metadata=bounds(check=_session))
    # The hub is a Zenoh router; endpoints and observers are its clients, so
    # all traffic goes through the hub's router and every client sees every key
    # (with "peer", endpoints reach the hub only).
    mode: str = field(default="client", metadata=bounds(choices=("client", "peer")))
    hub_mode: str = field(default="router", metadata=bounds(choices=("router", "peer")))
    # Where the hub listens; endpoints connect there unless `connect` is given.
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    scouting: bool = False
    # An endpoint gives up (exit status 2, message naming the address) if it cannot
    # reach the hub within this long.
    connect_timeout_s: float = field(default=30.0, metadata=bounds(gt=0))
    lease_ms: int = field(default=1000, metadata=bounds(ge=100))
    # Zenoh's low-latency unicast transport: a message is written to the socket by the
    # thread that puts it, with no batching task to wake (fewer thread wake-ups per message;
    # no QoS priorities, which the loop does not need). A participant without it still
    # connects, over the usual transport.
    low_latency: bool = True
    # "mtls": TLS links, each participant proving its role with a certificate of the
    # experiment's CA (`neuvision certs`), and the hub's router admitting each role's
    # messages only on its own keys (hub.security). "password": the same, but TLS with the
    # hub's certificate only, each participant proving its role with a password
    # (`neuvision certs --passwords`). "none": plain TCP, no authentication.
    security: str = field(default="none", metadata=bounds(choices=SECURITY_MODES))
    # ca.pem, and <role>.pem + <role>.key ("mtls") or <role>.password ("password") of this
    # participant; the hub's folder also holds `passwords` (relative to the experiment file)
    certs_dir: str = ""

    def __post_init__(self) -> None:
        if not self.listen:
            raise ConfigError("listen: at least one address, where the hub listens")
        for key in ("listen", "connect"):
            for locator in getattr(self, key):
                why = _locator_problem(locator)
                if why:
                    raise ConfigError(f"{key}: {locator!r} {why}")
        if self.security == "none":
            return
        for key in ("listen", "connect"):
            plain = [loc for loc in getattr(self, key) if not loc.startswith("tls/")]
            if plain:
                raise ConfigError(
                    f"{key}: with bus.security = {self.security!r} every address is a TLS one "
                    f"(tls/HOST:PORT), got {plain}"
                )
        if self.mode != "client" or self.hub_mode != "router":
            raise ConfigError(
                f"mode, hub_mode: with bus.security = {self.security!r} the hub is the router "
                "(its access control sees every message) and the others its clients; got "
                f"mode = {self.mode!r}, hub_mode = {self.hub_mode!r}"
            )

    @property
    def keys(self) -> Keys:
        """The key expressions of this bus session (``session``)."""
        return Keys(self.session)


@dataclass(frozen=True)
class SchemeSection:
    """``[coding]`` or ``[decoding]``: a scheme named ``module:function`` and its parameters
    (docs/schemes.md)."""

    scheme: str = field(default="", metadata=bounds(check=_callable))
    params: dict = field(default_factory=dict)


@dataclass(frozen=True)
class EndpointSection:
    """``[body]`` or ``[culture]``: which endpoint kind serves the role, where it is started,
    and its own parameters (checked by its kind's ``check_config``)."""

    id: str = field(default="0", metadata=bounds(check=_key_chunk))  # on the bus's keys
    kind: str = ""
    # local: `neuvision run` starts it; external: started elsewhere, the hub waits for it.
    launch: str = field(default="local", metadata=bounds(choices=("local", "external")))
    # The CPUs the endpoint's process runs on (empty: wherever the OS puts it).
    cpus: tuple[int, ...] = field(default=(), metadata=CPUS)
    params: dict = field(default_factory=dict)


@dataclass(frozen=True)
class RecordSection:
    """``[record]``: whether the run is recorded, and how often the record is flushed."""

    enabled: bool = True
    flush_s: float = field(default=0.5, metadata=bounds(gt=0, le=1.0))


@dataclass(frozen=True)
class OnlineSection:
    """Burst and network-burst detection on the live spike stream (paper: "on the fly"),
    by the burst observer: a process beside the loop (hub/burst_observer.py)."""

    enabled: bool = True
    # "local": `neuvision run` starts the observer with the endpoints; "external": it is
    # started elsewhere (`neuvision observe bursts CONFIG --connect HOST`).
    launch: str = field(default="local", metadata=bounds(choices=("local", "external")))
    # Keyword arguments of hub.analysis BurstParams and NetworkBurstParams (their
    # defaults are the paper's: >= 3 spikes in 20 ms; >= 30 % of channels).
    burst: dict = field(default_factory=dict)
    network: dict = field(default_factory=dict)


@dataclass(frozen=True)
class DashboardSection:
    """The live dashboard (``neuvision dashboard``, ``neuvision run --dashboard``): where its
    page is served. It watches the bus as an observer and changes nothing of the run."""

    # 127.0.0.1: this machine only; "0.0.0.0" serves other machines too (anyone who can
    # reach the port can pause and stop the run).
    host: str = "127.0.0.1"
    # 0: a free port, chosen when the dashboard starts (and printed).
    port: int = field(default=8447, metadata=bounds(ge=0, le=65535))
    # Frames sent to the page per second (each frame carries the newest state; a page that
    # cannot keep up gets fewer, never older ones).
    fps: float = field(default=30.0, metadata=bounds(ge=1, le=120))
    # `neuvision run --dashboard` holds the run's first step until the dashboard watches
    # (it has read the run's world and subscribed), at most this long; 0: start at once.
    wait_s: float = field(default=20.0, metadata=bounds(ge=0, le=600))
    # A live dashboard takes a CPU only when the run's processes leave one idle
    # (SCHED_IDLE): it never takes a CPU the loop wants, and on full CPUs it sends fewer
    # frames. false: the ordinary scheduler (a busy machine of its own, far from the run).
    yield_cpu: bool = True


@dataclass(frozen=True)
class ExperimentConfig:
    """A whole experiment file, validated."""

    experiment: ExperimentSection = field(default_factory=ExperimentSection)
    loop: LoopSection = field(default_factory=LoopSection)
    policy: PolicySection = field(default_factory=PolicySection)
    bus: BusSection = field(default_factory=BusSection)
    coding: SchemeSection = field(
        default_factory=lambda: SchemeSection(scheme="hub.schemes:no_stimulation")
    )
    decoding: SchemeSection = field(
        default_factory=lambda: SchemeSection(scheme="hub.schemes:stopped")
    )
    body: EndpointSection = field(default_factory=lambda: EndpointSection(kind="sim_robot"))
    culture: EndpointSection = field(default_factory=lambda: EndpointSection(kind="sim_network"))
    record: RecordSection = field(default_factory=RecordSection)
    online: OnlineSection = field(default_factory=OnlineSection)
    dashboard: DashboardSection = field(default_factory=DashboardSection)
    # Parameters of the offline analysis (`neuvision analyze`): hub.analysis AnalysisParams
    # as a table (`bursts`, `network_bursts`, `psth_bin_ms`, ...), checked here, recorded
    # in the manifest, and read back from it by lab.run_analysis. Absent: the paper's.
    analysis: dict = field(default_factory=dict, metadata=bounds(check=_analysis))
    source: str = field(default="", metadata={"internal": True})

    def __post_init__(self) -> None:
        n = self.n_steps
        if not 1 <= n <= MAX_STEPS:
            raise ConfigError(
                f"experiment.duration_s = {self.experiment.duration_s} s at loop.period_ms = "
                f"{self.loop.period_ms} ms is {n:,} steps; a run takes 1 to {MAX_STEPS:,}"
            )

    def endpoint(self, role: str) -> EndpointSection:
        """The ``body`` or ``culture`` section."""
        return getattr(self, role)

    @property
    def n_steps(self) -> int:
        """Steps of the run: ``experiment.duration_s / loop.period_ms``, rounded."""
        return round(self.experiment.duration_s * 1e3 / self.loop.period_ms)

    def resolved(self) -> ExperimentConfig:
        """This config with each endpoint's params checked and resolved by its kind (the
        culture's and the world's contents in place): what a run records.

        See :func:`hub.launch.resolve_endpoints`; raises :class:`ConfigError`.
        """
        from hub.launch import resolve_endpoints  # the endpoint kinds import this module

        return resolve_endpoints(self)

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (TOML/JSON-ready), as recorded in the manifest (after
        :meth:`resolved`, with the culture's and the world's contents)."""
        return settings.to_plain(self)


# --------------------------------------------------------------------------- loading


def load_config(path: str | Path | None = None, overrides: list[str] = ()) -> ExperimentConfig:
    """Read and validate an experiment file.

    Parameters
    ----------
    path : path or None
        TOML file; None gives the defaults. It may start with ``extends = "base.toml"``
        (see :mod:`settings.files` for the merge rule). A recorded run's folder (or its
        ``manifest.json``) gives the config that run ran with, resolved: to run it again.
    overrides : list of str
        ``dotted.key=value`` items applied after the file; values are parsed as
        TOML values (``loop.period_ms=5``, ``experiment.name="x"``), falling back
        to a plain string. Paths in them are taken from the current folder.

    Raises
    ------
    ConfigError
        Naming the file or the dotted key, and the reason.
    """
    data: dict[str, Any] = {}
    if path is not None:
        recorded = recorded_config(path)
        if recorded is not None:
            data, path = recorded
        else:
            data = settings.load(path, "config file", PATH_KEYS)
    settings.apply_overrides(data, overrides, PATH_KEYS)
    cfg = from_dict(data)
    return dataclasses.replace(cfg, source=str(path) if path else "")


def recorded_config(path: str | Path) -> tuple[dict[str, Any], Path] | None:
    """The config a recorded run ran with (its manifest's, resolved: the culture's and the
    world's contents in place) and the run's folder, when ``path`` is that folder or its
    ``manifest.json``; None for anything else."""
    from hub.record import MANIFEST_FILE  # hub.record imports hub.protocol, as this does

    path = Path(path)
    if path.is_dir() and (path / MANIFEST_FILE).is_file():
        manifest, folder = path / MANIFEST_FILE, path
    elif path.name == MANIFEST_FILE and path.is_file():
        manifest, folder = path, path.parent
    else:
        return None
    try:
        config = json.loads(manifest.read_text()).get("config")
    except (OSError, ValueError, AttributeError) as exc:
        raise ConfigError(f"run folder {folder}: its manifest cannot be read ({exc})") from None
    if not isinstance(config, dict) or not config:
        raise ConfigError(f"run folder {folder}: its manifest holds no config to run again")
    return config, folder


def from_dict(data: dict[str, Any]) -> ExperimentConfig:
    """Validate a nested dict against :class:`ExperimentConfig`."""
    return settings.build(ExperimentConfig, data)


def check_value(dotted: str, kind: type, value, **limits) -> Any:
    """Check one value against a type and limits; return it typed.

    Parameters
    ----------
    dotted : str
        The value's name in the config (``section.key``), named by the error.
    kind : type
        What the value must be (bool, int, float, str, ...).
    value
        The value to check.
    **limits
        ``gt``, ``ge``, ``lt``, ``le``, ``choices``, ... as :func:`settings.schema.bounds`.

    Raises
    ------
    ConfigError
        The value is not of ``kind`` or not within the limits.
    """
    return settings.coerce(dotted, kind, value, bounds(**limits))
