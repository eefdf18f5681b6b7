"""Experiment configuration: TOML files, defaults, and validation by dotted key.

The defaults of every hub-level setting live in the dataclasses below and
nowhere else. :func:`load_config` reads a TOML file, applies ``key=value``
overrides, and validates every key: unknown or invalid ones are reported by
their dotted path (``loop.period_ms must be > 0, got -5``).

Endpoint-specific settings (``body.params``, ``culture.params``) are free tables
here; each endpoint kind validates its own, naming the same dotted paths.
"""

from __future__ import annotations

import dataclasses
import difflib
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hub.protocol import Keys


class ConfigError(ValueError):
    """A configuration key that is unknown, missing or invalid; names the key."""


def _check(*, gt=None, ge=None, le=None, choices=None, pattern=None):
    return {"gt": gt, "ge": ge, "le": le, "choices": choices, "pattern": pattern}


@dataclass(frozen=True)
class ExperimentSection:
    name: str = "experiment"
    seed: int = field(default=0, metadata=_check(ge=0))
    duration_s: float = field(default=10.0, metadata=_check(gt=0))
    runs_dir: str = "runs"
    notes: str = ""  # free text, kept in the manifest with the config


@dataclass(frozen=True)
class LoopSection:
    period_ms: float = field(default=10.0, metadata=_check(gt=0, le=10_000))
    mode: str = field(default="lockstep", metadata=_check(choices=("lockstep", "realtime")))
    # How long to wait for the required endpoints to appear before giving up.
    wait_timeout_s: float = field(default=30.0, metadata=_check(gt=0))
    # Lockstep: a reply not in after this long is counted missing (policy applies).
    reply_timeout_s: float = field(default=5.0, metadata=_check(gt=0))
    # Realtime: a reply must arrive within this long after its step's start
    # (0 means one period: before the next step starts).
    deadline_ms: float = field(default=0.0, metadata=_check(ge=0))
    status_hz: float = field(default=4.0, metadata=_check(gt=0, le=100))
    # Realtime: the SCHED_FIFO priority of the hub's threads during the steps (1-99; 0
    # leaves the scheduler alone). Refused without CAP_SYS_NICE/RLIMIT_RTPRIO: the run
    # goes on, and the manifest says so.
    realtime_priority: int = field(default=10, metadata=_check(ge=0, le=99))
    # The CPUs the hub's process runs on (empty: wherever the OS puts it). A CPU of its
    # own keeps the hub's threads from waiting behind the endpoints' (README, "CPU
    # placement"). Not for runs side by side: each would take the same CPUs.
    cpus: tuple[int, ...] = ()

    @property
    def deadline_s(self) -> float:
        return (self.deadline_ms or self.period_ms) / 1e3


@dataclass(frozen=True)
class PolicySection:
    # What the hub codes when a body's sensor reading is late or missing.
    missing_sensors: str = field(
        default="zero_stim", metadata=_check(choices=("zero_stim", "hold"))
    )
    # What the hub sends the body when a culture's spikes are late or missing.
    missing_spikes: str = field(
        default="stop_robot", metadata=_check(choices=("stop_robot", "hold"))
    )
    # What happens when a required endpoint dies mid-run.
    endpoint_death: str = field(default="stop", metadata=_check(choices=("stop", "continue")))


@dataclass(frozen=True)
class BusSection:
    session: str = field(default="default", metadata=_check(pattern="session"))
    # The hub is a Zenoh router; endpoints and observers are its clients, so
    # all traffic goes through the hub's router and every client sees every key
    # (with "peer", endpoints reach the hub only).
    mode: str = field(default="client", metadata=_check(choices=("client", "peer")))
    hub_mode: str = field(default="router", metadata=_check(choices=("router", "peer")))
    # Where the hub listens; endpoints connect there unless `connect` is given.
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    scouting: bool = False
    # An endpoint gives up (exit status 1, message naming the address) if it cannot
    # reach the hub within this long.
    connect_timeout_s: float = field(default=30.0, metadata=_check(gt=0))
    lease_ms: int = field(default=1000, metadata=_check(ge=100))
    # Zenoh's low-latency unicast transport: a message is written to the socket by the
    # thread that puts it, with no batching task to wake (fewer thread wake-ups per message;
    # no QoS priorities, which the loop does not need). A participant without it still
    # connects, over the usual transport.
    low_latency: bool = True

    @property
    def keys(self) -> Keys:
        return Keys(self.session)


@dataclass(frozen=True)
class SchemeSection:
    scheme: str = field(default="", metadata=_check(pattern="callable"))
    params: dict = field(default_factory=dict)


@dataclass(frozen=True)
class EndpointSection:
    id: str = "0"
    kind: str = ""
    # local: `neuvision run` starts it; external: started elsewhere, the hub waits for it.
    launch: str = field(default="local", metadata=_check(choices=("local", "external")))
    # The CPUs the endpoint's process runs on (empty: wherever the OS puts it).
    cpus: tuple[int, ...] = ()
    params: dict = field(default_factory=dict)


@dataclass(frozen=True)
class RecordSection:
    enabled: bool = True
    flush_s: float = field(default=0.5, metadata=_check(gt=0, le=1.0))


@dataclass(frozen=True)
class OnlineSection:
    """Burst and network-burst detection on the live spike stream (paper: "on the fly")."""

    enabled: bool = True
    # Keyword arguments of hub.analysis BurstParams and NetworkBurstParams (their
    # defaults are the paper's: >= 3 spikes in 20 ms; >= 30 % of channels).
    burst: dict = field(default_factory=dict)
    network: dict = field(default_factory=dict)


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
    source: str = field(default="", metadata={"internal": True})

    def endpoint(self, role: str) -> EndpointSection:
        return getattr(self, role)

    @property
    def n_steps(self) -> int:
        return round(self.experiment.duration_s * 1e3 / self.loop.period_ms)

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (TOML/JSON-ready), as recorded in the manifest."""
        out = dataclasses.asdict(self)
        out.pop("source")
        return _lists(out)


def _lists(value):
    if isinstance(value, dict):
        return {k: _lists(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_lists(v) for v in value]
    return value


# --------------------------------------------------------------------------- loading


def load_config(path: str | Path | None = None, overrides: list[str] = ()) -> ExperimentConfig:
    """Read and validate an experiment file.

    Parameters
    ----------
    path : path or None
        TOML file; None gives the defaults.
    overrides : list of str
        ``dotted.key=value`` items applied after the file; values are parsed as
        TOML values (``loop.period_ms=5``, ``experiment.name="x"``), falling back
        to a plain string.

    Raises
    ------
    ConfigError
        Naming the dotted key and the reason.
    """
    data: dict[str, Any] = _read_toml(Path(path)) if path is not None else {}
    # (A file may start with extends = "base.toml": see _read_toml.)
    for item in overrides:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"override {item!r} must look like dotted.key=value")
        _set_dotted(data, key.strip(), _parse_value(text.strip()))
    cfg = from_dict(data)
    return dataclasses.replace(cfg, source=str(path) if path else "")


def _read_toml(path: Path, seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    """Read a TOML file; ``extends = "other.toml"`` (relative to it) is merged under it."""
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"config file {path} does not exist") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    base_name = data.pop("extends", None)
    if base_name is None:
        return data
    if not isinstance(base_name, str):
        raise ConfigError(f"{path}: extends must be a file name, got {base_name!r}")
    base_path = (path.parent / base_name).resolve()
    if base_path in seen:
        raise ConfigError(f"{path}: extends {base_name} makes a cycle")
    return _merge(_read_toml(base_path, seen + (path.resolve(),)), data)


def _merge(base: dict, over: dict) -> dict:
    """Tables merge key by key, except ``params`` tables, which replace (they belong
    to one scheme or endpoint kind, and the extending file may name another)."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict) and key != "params":
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def from_dict(data: dict[str, Any]) -> ExperimentConfig:
    """Validate a nested dict against :class:`ExperimentConfig`."""
    return _build(ExperimentConfig, data, "")


def _parse_value(text: str) -> Any:
    try:
        return tomllib.loads(f"x = {text}")["x"]
    except tomllib.TOMLDecodeError:
        return text


def _set_dotted(data: dict, key: str, value: Any) -> None:
    parts = key.split(".")
    node = data
    for part in parts[:-1]:
        node = node.setdefault(part, {})
        if not isinstance(node, dict):
            raise ConfigError(f"override {key}: {part} is not a table")
    node[parts[-1]] = value


def _build(cls, data: Any, prefix: str):
    if not isinstance(data, dict):
        raise ConfigError(f"{prefix.rstrip('.')} must be a table, got {type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls) if not f.metadata.get("internal")}
    for key in data:
        if key not in fields:
            hint = difflib.get_close_matches(key, fields, n=1)
            extra = f" (did you mean {hint[0]}?)" if hint else ""
            known = ", ".join(fields)
            raise ConfigError(f"{prefix}{key} is not a known key{extra}; known: {known}")
    hints = typing.get_type_hints(cls)
    values = {}
    for name, f in fields.items():
        if name not in data:
            continue
        dotted = prefix + name
        hint = hints[name]
        value = data[name]
        if dataclasses.is_dataclass(hint):
            base = f.default_factory() if f.default_factory is not dataclasses.MISSING else hint()
            merged = {**_shallow(base), **value} if isinstance(value, dict) else value
            values[name] = _build(hint, merged, dotted + ".")
        else:
            values[name] = _coerce(dotted, hint, value, f.metadata)
    return cls(**values)


def _shallow(obj) -> dict:
    """Non-default fields of a section default (so scheme defaults survive a partial table)."""
    return {
        f.name: getattr(obj, f.name)
        for f in dataclasses.fields(obj)
        if not f.metadata.get("internal")
    }


def check_value(dotted: str, kind: type, value, **limits) -> Any:
    """Check one value against a type and ``gt``/``ge``/``le`` limits; error names ``dotted``."""
    return _coerce(dotted, kind, value, limits)


def _coerce(dotted: str, hint, value, meta) -> Any:
    origin = typing.get_origin(hint)
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{dotted} must be true or false, got {value!r}")
    elif hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{dotted} must be an integer, got {value!r}")
    elif hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{dotted} must be a number, got {value!r}")
        value = float(value)
        if value != value or value in (float("inf"), float("-inf")):
            raise ConfigError(f"{dotted} must be finite, got {value}")
    elif hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{dotted} must be a string, got {value!r}")
    elif origin is tuple and typing.get_args(hint)[0] is int:
        if not isinstance(value, (list, tuple)) or not all(
            isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in value
        ):
            raise ConfigError(f"{dotted} must be a list of CPU numbers (>= 0), got {value!r}")
        if len(set(value)) != len(value):
            raise ConfigError(f"{dotted} names a CPU twice: {value!r}")
        value = tuple(value)
    elif origin is tuple:
        if isinstance(value, str):
            value = [value]
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            raise ConfigError(f"{dotted} must be a list of strings, got {value!r}")
        value = tuple(value)
    elif hint is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{dotted} must be a table, got {value!r}")
    elif isinstance(hint, type) and not isinstance(value, hint):
        raise ConfigError(f"{dotted} must be a {hint.__name__}, got {value!r}")
    gt, ge, le = meta.get("gt"), meta.get("ge"), meta.get("le")
    if gt is not None and not value > gt:
        raise ConfigError(f"{dotted} must be > {gt}, got {value}")
    if ge is not None and not value >= ge:
        raise ConfigError(f"{dotted} must be >= {ge}, got {value}")
    if le is not None and not value <= le:
        raise ConfigError(f"{dotted} must be <= {le}, got {value}")
    choices = meta.get("choices")
    if choices and value not in choices:
        raise ConfigError(f"{dotted} must be one of {', '.join(choices)}; got {value!r}")
    pattern = meta.get("pattern")
    if pattern == "session":
        try:
            Keys(value)
        except ValueError as exc:
            raise ConfigError(f"{dotted}: {exc}") from None
    if pattern == "callable" and value.count(":") != 1:
        raise ConfigError(f"{dotted} must name a callable as module:function, got {value!r}")
    return value
