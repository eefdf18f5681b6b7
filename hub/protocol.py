"""The wire contract: message schemas, their msgpack encoding, and key expressions.

Every message crossing the bus is defined here and nowhere else. A message is a
frozen dataclass with ``encode() -> bytes`` and ``Cls.decode(bytes) -> Cls``.
Decoding validates everything (types, versions, array lengths and dtypes,
finiteness, ranges) and raises :class:`ProtocolError`, whose ``kind`` is a short
category that receivers use to count what they drop.

Numeric arrays travel as msgpack ``bin`` holding little-endian data of the dtype
named by the schema, never as lists of floats.
"""

from __future__ import annotations

import dataclasses
import math
import operator
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import msgpack
import numpy as np

SCHEMA_VERSION = 1
ROLES = ("body", "culture")
MAX_MESSAGE_BYTES = 64 * 1024 * 1024
SMALL_ARRAY = 64


class ProtocolError(ValueError):
    """A message that does not satisfy its schema.

    Parameters
    ----------
    kind : str
        Short category used for counting drops: ``not_msgpack``, ``not_a_map``,
        ``version``, ``missing``, ``unknown``, ``type``, ``array``,
        ``non_finite``, ``range``, ``inconsistent``.
    message : str
        What is wrong, naming the field.
    """

    def __init__(self, kind: str, message: str):
        super().__init__(f"{kind}: {message}")
        self.kind = kind


# --------------------------------------------------------------------------- keys


@dataclass(frozen=True)
class Keys:
    """Key expressions of one NeuVision session (``nv/<session>/...``)."""

    session: str = "default"

    def __post_init__(self):
        bad = set("/*$?#") & set(self.session)
        if not self.session or bad:
            raise ValueError(f"session name must be non-empty without {sorted(bad)}")

    @property
    def root(self) -> str:
        return f"nv/{self.session}"

    def input(self, role: str, id: str) -> str:
        """Hub → endpoint: motor commands for a body, stimulation for a culture."""
        return self.motor(id) if role == "body" else self.stim(id)

    def output(self, role: str, id: str) -> str:
        """Endpoint → hub: sensor readings of a body, spikes of a culture."""
        return self.sensors(id) if role == "body" else self.spikes(id)

    def motor(self, id: str) -> str:
        return f"{self.root}/body/{id}/motor"

    def sensors(self, id: str) -> str:
        return f"{self.root}/body/{id}/sensors"

    def stim(self, id: str) -> str:
        return f"{self.root}/culture/{id}/stim"

    def spikes(self, id: str) -> str:
        return f"{self.root}/culture/{id}/spikes"

    def potentials(self, id: str) -> str:
        return f"{self.root}/culture/{id}/potentials"

    def describe(self, role: str, id: str) -> str:
        return f"{self.root}/{role}/{id}/describe"

    def alive(self, role: str, id: str) -> str:
        return f"{self.root}/alive/{role}/{id}"

    @property
    def alive_all(self) -> str:
        return f"{self.root}/alive/**"

    @property
    def hub_status(self) -> str:
        return f"{self.root}/hub/status"

    @property
    def hub_control(self) -> str:
        return f"{self.root}/hub/control"

    def parse_alive(self, key: str) -> tuple[str, str] | None:
        """``nv/<s>/alive/<role>/<id>`` → ``(role, id)``, or None for another key."""
        prefix = f"{self.root}/alive/"
        if not key.startswith(prefix):
            return None
        parts = key[len(prefix) :].split("/")
        if len(parts) != 2 or parts[0] not in ROLES and parts[0] != "hub":
            return None
        return parts[0], parts[1]


# --------------------------------------------------------------------------- field specs


@dataclass(frozen=True)
class Scalar:
    """A scalar field: ``kind`` is int, float, bool or str."""

    kind: type
    min: float | None = None
    max: float | None = None
    optional: bool = False


@dataclass(frozen=True)
class Array:
    """A numeric array field, carried as little-endian ``bin`` of ``dtype``.

    ``length`` fixes the length; ``group`` names a set of parallel arrays that
    must share one length.
    """

    dtype: str
    length: int | None = None
    group: str | None = None
    min: float | None = None
    max: float | None = None
    optional: bool = False

    def __post_init__(self):
        wire = np.dtype(self.dtype)
        object.__setattr__(self, "wire", wire)
        object.__setattr__(self, "native", wire.newbyteorder("="))


@dataclass(frozen=True)
class Mapping:
    """A free-form map of str keys (counters, config); values are not typed."""

    optional: bool = False


@dataclass(frozen=True)
class StrList:
    """A list of str."""

    optional: bool = False


def _check_scalar(name: str, spec: Scalar, value: Any) -> Any:
    kind = spec.kind
    if kind is float and type(value) is float and spec.min is None and math.isfinite(value):
        return value
    if kind is bool:
        if not isinstance(value, bool):
            raise ProtocolError("type", f"{name} must be a bool, got {type(value).__name__}")
        return value
    if kind is str:
        if not isinstance(value, str):
            raise ProtocolError("type", f"{name} must be a str, got {type(value).__name__}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ProtocolError("type", f"{name} must be a number, got {type(value).__name__}")
    if kind is int:
        if not isinstance(value, int):
            raise ProtocolError("type", f"{name} must be an integer, got {value!r}")
    else:
        value = float(value)
        if not math.isfinite(value):
            raise ProtocolError("non_finite", f"{name} must be finite, got {value}")
    if spec.min is not None and value < spec.min:
        raise ProtocolError("range", f"{name} must be >= {spec.min}, got {value}")
    if spec.max is not None and value > spec.max:
        raise ProtocolError("range", f"{name} must be <= {spec.max}, got {value}")
    return value


def _decode_array(name: str, spec: Array, value: Any) -> np.ndarray:
    """``bin`` → array of the schema's dtype (values are checked at construction)."""
    if not isinstance(value, bytes):
        raise ProtocolError(
            "type", f"{name} must be bin of {spec.dtype}, got {type(value).__name__}"
        )
    dtype = spec.wire
    if len(value) % dtype.itemsize:
        raise ProtocolError(
            "array", f"{name} has {len(value)} bytes, not a multiple of {dtype.itemsize}"
        )
    arr = np.frombuffer(value, dtype=dtype)
    return arr if dtype.isnative else arr.astype(dtype.newbyteorder("="))


def _as_array(name: str, spec: Array, value: Any) -> np.ndarray:
    dtype = spec.native
    if type(value) is np.ndarray and value.ndim == 1 and value.dtype == dtype:
        return value
    try:
        return np.ascontiguousarray(value, dtype=dtype).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ProtocolError("type", f"{name} is not convertible to {dtype}: {exc}") from None


def _check_array_values(name: str, spec: Array, arr: np.ndarray) -> None:
    if spec.length is not None and arr.size != spec.length:
        raise ProtocolError("array", f"{name} must have {spec.length} values, got {arr.size}")
    if not arr.size:
        return
    is_float = arr.dtype.kind == "f"
    if not (is_float or spec.min is not None or spec.max is not None):
        return
    if arr.size <= SMALL_ARRAY:  # plain Python is faster than numpy calls here
        values = arr.tolist()
        finite = not is_float or all(map(math.isfinite, values))
        lo, hi = (min(values), max(values)) if finite else (0, 0)
    else:  # min and max propagate NaN: two reductions check finiteness and range
        lo, hi = arr.min(), arr.max()
        finite = not is_float or bool(np.isfinite(lo) and np.isfinite(hi))
    if not finite:
        raise ProtocolError("non_finite", f"{name} holds NaN or infinity")
    if spec.min is not None and lo < spec.min:
        raise ProtocolError("range", f"{name} must be >= {spec.min}, got {lo}")
    if spec.max is not None and hi > spec.max:
        raise ProtocolError("range", f"{name} must be <= {spec.max}, got {hi}")


def _quick_check(spec) -> Callable[[Any], bool]:
    """A predicate that is True only for a value the full check would take unchanged
    (exact type, in range); anything else, valid or not, gets the full check."""
    if isinstance(spec, Scalar):
        kind, lo, hi, optional = spec.kind, spec.min, spec.max, spec.optional
        if kind is float:
            lo = -math.inf if lo is None else lo
            hi = math.inf if hi is None else hi

            def accepts(value):  # a NaN fails both comparisons
                return type(value) is float and lo <= value <= hi and value - value == 0.0

        else:
            lo = -math.inf if lo is None else lo
            hi = math.inf if hi is None else hi
            ranged = kind is int

            def accepts(value):
                return type(value) is kind and (not ranged or lo <= value <= hi)

    elif isinstance(spec, Array):
        dtype, length, optional = spec.native, spec.length, spec.optional
        ranged = dtype.kind == "f" or spec.min is not None or spec.max is not None
        lo = -math.inf if spec.min is None else spec.min
        hi = math.inf if spec.max is None else spec.max

        def accepts(value):
            if type(value) is not np.ndarray or value.ndim != 1 or value.dtype != dtype:
                return False
            if length is not None and value.size != length:
                return False
            if ranged and value.size:
                if value.size > SMALL_ARRAY:  # min and max propagate NaN
                    low, high = float(value.min()), float(value.max())
                    finite = math.isfinite(low) and math.isfinite(high)
                else:
                    values = value.tolist()
                    low, high = min(values), max(values)
                    finite = dtype.kind != "f" or all(map(math.isfinite, values))
                if not (finite and lo <= low and high <= hi):
                    return False
            if value.base is None:
                value.flags.writeable = False
            return True

    elif isinstance(spec, Mapping):
        optional = spec.optional

        def accepts(value):
            return type(value) is dict

    else:
        optional = spec.optional

        def accepts(value):
            return type(value) is list and all(type(v) is str for v in value)

    if optional:
        return lambda value: value is None or accepts(value)
    return accepts


# --------------------------------------------------------------------------- base


class Message:
    """Base of every wire message: schema-driven encode, decode and validation.

    Subclasses are frozen dataclasses declaring ``SCHEMA`` (field name → spec).
    Construction validates and normalises (arrays to their schema dtype), so a
    message that exists is a valid one, whether built locally or decoded.
    """

    SCHEMA: ClassVar[dict[str, Scalar | Array | Mapping | StrList]]

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        cls._KNOWN = frozenset(cls.SCHEMA) | {"v"}
        cls._QUICK = tuple(
            (name, _quick_check(spec), getattr(spec, "group", None))
            for name, spec in cls.SCHEMA.items()
        )

    def __post_init__(self):
        if not self._accepted_at_once():
            self._validate_fields()
        self._check()

    def _accepted_at_once(self) -> bool:
        """The quick path of validation: True if every field already has its schema type
        and passes its checks, so nothing needs converting. False sends the message to
        :meth:`_validate_fields`, which converts what it can and names what is wrong."""
        values = self.__dict__
        sizes: dict[str, int] = {}
        for name, accepts, group in self._QUICK:
            value = values[name]
            if not accepts(value):
                return False
            if group and value is not None and sizes.setdefault(group, value.size) != value.size:
                return False
        return True

    def _validate_fields(self) -> None:
        groups: dict[str, tuple[str, int]] = {}
        for name, spec in self.SCHEMA.items():
            value = getattr(self, name)
            if value is None:
                if not spec.optional:
                    raise ProtocolError("missing", f"{type(self).__name__}.{name} is required")
                continue
            if isinstance(spec, Array):
                arr = _as_array(name, spec, value)
                _check_array_values(name, spec, arr)
                if arr.base is None:
                    arr.flags.writeable = False
                if arr is not value:
                    object.__setattr__(self, name, arr)
                if spec.group:
                    first = groups.setdefault(spec.group, (name, arr.size))
                    if first[1] != arr.size:
                        raise ProtocolError(
                            "inconsistent",
                            f"{name} has {arr.size} values but {first[0]} has {first[1]}",
                        )
            elif isinstance(spec, Scalar):
                checked = _check_scalar(name, spec, value)
                if checked is not value:
                    object.__setattr__(self, name, checked)
            elif isinstance(spec, StrList):
                if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                    raise ProtocolError("type", f"{name} must be a list of str")
            elif not isinstance(value, dict):
                raise ProtocolError("type", f"{name} must be a map")

    def _check(self) -> None:
        """Cross-field rules; subclasses override."""

    def to_dict(self) -> dict[str, Any]:
        """The msgpack-ready map: arrays as little-endian bytes, ``v`` added."""
        out: dict[str, Any] = {"v": SCHEMA_VERSION}
        for name, spec in self.SCHEMA.items():
            value = getattr(self, name)
            if value is None:
                continue
            if isinstance(spec, Array):
                value = value.astype(spec.wire, copy=False).tobytes()
            out[name] = value
        return out

    def encode(self) -> bytes:
        return msgpack.packb(self.to_dict(), use_bin_type=True)

    @classmethod
    def decode(cls, raw: bytes | bytearray | memoryview):
        """Parse and validate ``raw``; raise :class:`ProtocolError` if it is not a ``cls``."""
        data = unpack_map(raw)
        return cls.from_dict(data)

    @classmethod
    def from_dict(cls, data: dict[str, Any]):
        version = data.get("v")
        if version != SCHEMA_VERSION:
            raise ProtocolError("version", f"v must be {SCHEMA_VERSION}, got {version!r}")
        if not data.keys() <= cls._KNOWN:
            unknown = sorted(set(data) - cls._KNOWN)
            raise ProtocolError("unknown", f"{cls.__name__} has no field(s) {unknown}")
        values = {}
        for name, spec in cls.SCHEMA.items():
            if name not in data:
                if not spec.optional:
                    raise ProtocolError("missing", f"{cls.__name__}.{name} is missing")
                values[name] = None
                continue
            value = data[name]
            if isinstance(spec, Array):
                value = _decode_array(name, spec, value)
            values[name] = value
        return cls(**values)

    def __eq__(self, other):
        if type(other) is not type(self):
            return NotImplemented
        for f in dataclasses.fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if a is None or b is None or not np.array_equal(a, b):
                    return False
            elif a != b:
                return False
        return True

    __hash__ = None


def unpack_map(raw: bytes | bytearray | memoryview) -> dict[str, Any]:
    """msgpack bytes → dict with str keys, or :class:`ProtocolError`."""
    if len(raw) > MAX_MESSAGE_BYTES:
        raise ProtocolError("not_msgpack", f"message of {len(raw)} bytes exceeds the limit")
    try:
        data = msgpack.unpackb(bytes(raw), raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types
        raise ProtocolError("not_msgpack", f"undecodable payload ({type(exc).__name__})") from None
    if not isinstance(data, dict):
        raise ProtocolError("not_a_map", f"payload is a {type(data).__name__}, not a map")
    return data


_STEP = Scalar(int, min=0)


# --------------------------------------------------------------------------- messages


@dataclass(frozen=True, eq=False)
class MotorCommand(Message):
    """Hub → body: wheel speeds for one step (zeros at step 0)."""

    step: int
    left_mps: float
    right_mps: float
    v_mps: float | None = None
    omega_rad_s: float | None = None

    SCHEMA = {
        "step": _STEP,
        "left_mps": Scalar(float),
        "right_mps": Scalar(float),
        "v_mps": Scalar(float, optional=True),
        "omega_rad_s": Scalar(float, optional=True),
    }

    @classmethod
    def stop(cls, step: int) -> MotorCommand:
        return cls(step=step, left_mps=0.0, right_mps=0.0, v_mps=0.0, omega_rad_s=0.0)


@dataclass(frozen=True, eq=False)
class SensorReading(Message):
    """Body → hub: range finders, pose and contact at the end of a step."""

    step: int
    t_s: float
    ranges_m: np.ndarray
    pose: np.ndarray
    contact: bool

    SCHEMA = {
        "step": _STEP,
        "t_s": Scalar(float, min=0.0),
        "ranges_m": Array("<f4", min=0.0),
        "pose": Array("<f8", length=3),
        "contact": Scalar(bool),
    }


@dataclass(frozen=True, eq=False)
class Stimulation(Message):
    """Hub → culture: the pulses to deliver during a step (parallel arrays)."""

    step: int
    channel: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint32))
    amplitude_ua: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    width_ms: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    onset_ms: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))

    SCHEMA = {
        "step": _STEP,
        "channel": Array("<u4", group="pulse"),
        "amplitude_ua": Array("<f4", group="pulse"),
        "width_ms": Array("<f4", group="pulse", min=0.0),
        "onset_ms": Array("<f4", group="pulse", min=0.0),
    }

    @property
    def n_pulses(self) -> int:
        return int(self.channel.size)


@dataclass(frozen=True, eq=False)
class SpikeBatch(Message):
    """Culture → hub: spikes fired in the window ``[t0_s, t1_s)``, sorted by time."""

    step: int
    t0_s: float
    t1_s: float
    channel: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint32))
    t_ms: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))

    SCHEMA = {
        "step": _STEP,
        "t0_s": Scalar(float, min=0.0),
        "t1_s": Scalar(float, min=0.0),
        "channel": Array("<u4", group="spike"),
        "t_ms": Array("<f4", group="spike", min=0.0),
    }

    def _check(self):
        if self.t1_s < self.t0_s:
            raise ProtocolError("inconsistent", f"t1_s {self.t1_s} precedes t0_s {self.t0_s}")
        t_ms = self.t_ms
        if t_ms.size:
            if t_ms.size <= SMALL_ARRAY:
                values = t_ms.tolist()
                unsorted = any(map(operator.gt, values, values[1:]))
            else:
                unsorted = bool((t_ms[1:] < t_ms[:-1]).any())
            if unsorted:
                raise ProtocolError("inconsistent", "t_ms must be sorted")
            window_ms = (self.t1_s - self.t0_s) * 1e3
            if t_ms[-1] > window_ms * (1 + 1e-6) + 1e-3:
                raise ProtocolError(
                    "range", f"t_ms {t_ms[-1]} lies beyond the {window_ms} ms window"
                )


@dataclass(frozen=True, eq=False)
class Potentials(Message):
    """Sim culture → observers: a low-rate snapshot of membrane potentials."""

    step: int
    t_s: float
    v_mv: np.ndarray

    SCHEMA = {"step": _STEP, "t_s": Scalar(float, min=0.0), "v_mv": Array("<f4")}


@dataclass(frozen=True, eq=False)
class Description(Message):
    """Reply of an endpoint's ``describe`` queryable: what it is and its geometry.

    A culture lists its channels (``channel``, ``x_um``, ``y_um``, and for
    simulated neurons ``cell_type``: 0 excitatory, 1 inhibitory). A body lists
    its range finders and drive geometry. ``counters`` reports what the
    endpoint has dropped, by kind.
    """

    role: str
    id: str
    kind: str
    channel: np.ndarray | None = None
    x_um: np.ndarray | None = None
    y_um: np.ndarray | None = None
    cell_type: np.ndarray | None = None
    sensor_angles_rad: np.ndarray | None = None
    max_range_m: float | None = None
    wheel_base_m: float | None = None
    radius_m: float | None = None
    max_wheel_mps: float | None = None
    counters: dict | None = None

    SCHEMA = {
        "role": Scalar(str),
        "id": Scalar(str),
        "kind": Scalar(str),
        "channel": Array("<u4", group="chan", optional=True),
        "x_um": Array("<f4", group="chan", optional=True),
        "y_um": Array("<f4", group="chan", optional=True),
        "cell_type": Array("u1", group="chan", max=1, optional=True),
        "sensor_angles_rad": Array("<f4", optional=True),
        "max_range_m": Scalar(float, min=0.0, optional=True),
        "wheel_base_m": Scalar(float, min=0.0, optional=True),
        "radius_m": Scalar(float, min=0.0, optional=True),
        "max_wheel_mps": Scalar(float, min=0.0, optional=True),
        "counters": Mapping(optional=True),
    }

    BODY_FIELDS: ClassVar = (
        "sensor_angles_rad",
        "max_range_m",
        "wheel_base_m",
        "radius_m",
        "max_wheel_mps",
    )
    CULTURE_FIELDS: ClassVar = ("channel", "x_um", "y_um")

    def _check(self):
        if self.role not in ROLES:
            raise ProtocolError("range", f"role must be one of {ROLES}, got {self.role!r}")
        needed = self.BODY_FIELDS if self.role == "body" else self.CULTURE_FIELDS
        missing = [n for n in needed if getattr(self, n) is None]
        if missing:
            raise ProtocolError("missing", f"a {self.role} description needs {missing}")
        if self.role == "culture" and np.unique(self.channel).size != self.channel.size:
            raise ProtocolError("inconsistent", "channel ids must be unique")

    @property
    def n_sensors(self) -> int:
        return int(self.sensor_angles_rad.size)


@dataclass(frozen=True, eq=False)
class HubStatus(Message):
    """Hub → observers, a few times a second."""

    step: int
    t_s: float
    mode: str
    state: str
    late: dict
    missing: dict
    dropped: dict
    alive: list
    wall_s: float = 0.0
    steps_per_s: float = 0.0
    extra: dict | None = None

    STATES: ClassVar = ("waiting", "running", "paused", "stopped")

    SCHEMA = {
        "step": _STEP,
        "t_s": Scalar(float, min=0.0),
        "mode": Scalar(str),
        "state": Scalar(str),
        "late": Mapping(),
        "missing": Mapping(),
        "dropped": Mapping(),
        "alive": StrList(),
        "wall_s": Scalar(float, min=0.0),
        "steps_per_s": Scalar(float, min=0.0),
        "extra": Mapping(optional=True),
    }

    def _check(self):
        if self.state not in self.STATES:
            raise ProtocolError("range", f"state must be one of {self.STATES}, got {self.state!r}")


CONTROL_COMMANDS = ("status", "pause", "resume", "stop", "config")


@dataclass(frozen=True, eq=False)
class ControlRequest(Message):
    """Payload of a query on ``hub/control``."""

    cmd: str

    SCHEMA = {"cmd": Scalar(str)}

    def _check(self):
        if self.cmd not in CONTROL_COMMANDS:
            raise ProtocolError("range", f"cmd must be one of {CONTROL_COMMANDS}, got {self.cmd!r}")


@dataclass(frozen=True, eq=False)
class ControlReply(Message):
    """Reply of ``hub/control``: whether the command was taken, the state, and data."""

    ok: bool
    state: str
    reason: str = ""
    data: dict | None = None

    SCHEMA = {
        "ok": Scalar(bool),
        "state": Scalar(str),
        "reason": Scalar(str),
        "data": Mapping(optional=True),
    }


INPUT_TYPE = {"body": MotorCommand, "culture": Stimulation}
OUTPUT_TYPE = {"body": SensorReading, "culture": SpikeBatch}
