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
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated, Any, ClassVar

import msgpack
import msgspec
import numpy as np

from hub.wire import MAX_MESSAGE_BYTES  # what the wire reassembles, decoded whole

SCHEMA_VERSION = 4
# Versions read as this one: a version-3 message is a version-4 message (v4 only added the
# optional ``SpikeBatch.partial``), so runs recorded under v3 stay readable.
READ_VERSIONS = (3, 4)
ROLES = ("body", "culture")
SMALL_ARRAY = 64
_FMAX = sys.float_info.max  # a finite bound: ``-_FMAX <= x <= _FMAX`` is False for NaN and inf


def kernels():
    """The compiled checks of larger arrays (``hub/array_kernels.py``), imported on first
    use: a command that never checks one does not import numba."""
    global _kernels
    if _kernels is None:
        from hub import array_kernels

        _kernels = array_kernels
    return _kernels


_kernels = None


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


def key_chunk_problem(text: str, what: str) -> str:
    """Why ``text`` cannot be one chunk of a key expression (a session name, an endpoint's
    id), or "" when it can.

    Parameters
    ----------
    text : str
        The candidate chunk.
    what : str
        What it names, to begin the message with (``"session name"``).
    """
    if not text:
        return f"{what} is needed (it may not be empty)"
    bad = set("/*$?#") & set(text)
    if bad:
        return (
            f"{what} {text!r} may not hold {' '.join(sorted(bad))} (they are Zenoh's key "
            "separators and wildcards)"
        )
    return ""


@dataclass(frozen=True)
class Keys:
    """Key expressions of one NeuVision session (``nv/<session>/...``)."""

    session: str = "default"

    def __post_init__(self):
        problem = key_chunk_problem(self.session, "session name")
        if problem:
            raise ValueError(problem)

    @property
    def root(self) -> str:
        """``nv/<session>``, the prefix of every key of the session."""
        return f"nv/{self.session}"

    def input(self, role: str, id: str) -> str:
        """Hub → endpoint: motor commands for a body, stimulation for a culture.

        Parameters
        ----------
        role : str
            ``"body"``; any other role is taken for a culture.
        id : str
            The endpoint's id.
        """
        return self.motor(id) if role == "body" else self.stim(id)

    def output(self, role: str, id: str) -> str:
        """Endpoint → hub: sensor readings of a body, spikes of a culture.

        Parameters
        ----------
        role : str
            ``"body"``; any other role is taken for a culture.
        id : str
            The endpoint's id.
        """
        return self.sensors(id) if role == "body" else self.spikes(id)

    def motor(self, id: str) -> str:
        """Hub → body ``id``: its ``MotorCommand``."""
        return f"{self.root}/body/{id}/motor"

    def sensors(self, id: str) -> str:
        """Body ``id`` → hub: its ``SensorReading``."""
        return f"{self.root}/body/{id}/sensors"

    def stim(self, id: str) -> str:
        """Hub → culture ``id``: its ``Stimulation``."""
        return f"{self.root}/culture/{id}/stim"

    def spikes(self, id: str) -> str:
        """Culture ``id`` → hub: its ``SpikeBatch``."""
        return f"{self.root}/culture/{id}/spikes"

    @property
    def outputs_all(self) -> str:
        """Every endpoint's output (``sensors`` and ``spikes`` of any id) in one key
        expression. It must not match the inputs the hub puts (``stim``): a subscription
        of the hub's that matches its own puts costs each of them ~5 µs of routing, even
        with local delivery turned off."""
        return f"{self.root}/*/*/s$*s"

    def potentials(self, id: str) -> str:
        """Simulated culture ``id`` → observers: its ``Potentials`` snapshots."""
        return f"{self.root}/culture/{id}/potentials"

    def describe(self, role: str, id: str) -> str:
        """Queryable of each endpoint: its ``Description``.

        Parameters
        ----------
        role : str
            ``"body"`` or ``"culture"``; ``"*"`` for a key expression of any.
        id : str
            The endpoint's id, or ``"*"``.
        """
        return f"{self.root}/{role}/{id}/describe"

    def run(self, role: str, id: str) -> str:
        """Queryable of each endpoint: the hub's ``RunStart`` / ``RunEnd`` → ``RunReply``.

        Parameters
        ----------
        role : str
            ``"body"`` or ``"culture"``; ``"*"`` for a key expression of any.
        id : str
            The endpoint's id, or ``"*"``.
        """
        return f"{self.root}/{role}/{id}/run"

    def alive(self, role: str, id: str) -> str:
        """The liveliness token of a participant: ``nv/<session>/alive/<role>/<id>``.

        Parameters
        ----------
        role : str
            An endpoint's role, ``"hub"`` or ``"observer"`` (see :meth:`parse_alive`).
        id : str
            Its id (an observer's name), or ``"*"``.
        """
        return f"{self.root}/alive/{role}/{id}"

    @property
    def hub_alive(self) -> str:
        """The hub's liveliness token (one hub a session: id ``0``)."""
        return self.alive("hub", "0")

    @property
    def alive_all(self) -> str:
        """Every liveliness token of the session (endpoints, hub, observers)."""
        return f"{self.root}/alive/**"

    @property
    def hub_status(self) -> str:
        """Hub → observers: ``HubStatus``, published a few times a second and answered
        on query."""
        return f"{self.root}/hub/status"

    @property
    def hub_control(self) -> str:
        """Queryable of the hub: a ``ControlRequest`` → ``ControlReply`` (hub/ctl.py)."""
        return f"{self.root}/hub/control"

    @property
    def hub_view(self) -> str:
        """Hub → observers, asked for: ``HubView``, what the loop carried, for live
        displays; a queryable on ``hub/view/*`` (``?after=MARK``: the views after the one
        named MARK, each on ``hub/view/<its name>``; hub/view.py)."""
        return f"{self.root}/hub/view"

    def observer_run(self, name: str) -> str:
        """Queryable of an observer (``name``: ``bursts``): the hub's ``ObserverStart`` /
        ``ObserverEnd``."""
        return f"{self.root}/observer/{name}/run"

    def observer_spikes(self, name: str) -> str:
        """Hub → observer: the culture's spikes (``ObservedSpikes``), sealed."""
        return f"{self.root}/observer/{name}/spikes"

    def observer_reports(self, name: str) -> str:
        """Observer → hub and live displays: its findings (``BurstReport``), sealed."""
        return f"{self.root}/observer/{name}/reports"

    def parse_alive(self, key: str) -> tuple[str, str] | None:
        """``nv/<s>/alive/<role>/<id>`` → ``(role, id)``, or None for another key; the
        roles are the endpoints', ``hub`` and ``observer``."""
        prefix = f"{self.root}/alive/"
        if not key.startswith(prefix):
            return None
        parts = key[len(prefix) :].split("/")
        if len(parts) != 2 or parts[0] not in (*ROLES, "hub", "observer"):
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


@dataclass(frozen=True)
class BlobList:
    """A list of opaque byte strings (msgpack ``bin`` each)."""

    optional: bool = False


@dataclass(frozen=True)
class Blob:
    """Opaque bytes (msgpack ``bin``) of a fixed length."""

    length: int
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
    arr = np.frombuffer(value, dtype)  # read-only: it views the immutable bytes
    return arr if dtype.isnative else arr.astype(spec.native)


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


def _valid_values(spec: Array) -> Callable[[np.ndarray], bool]:
    """A predicate on a 1-D array of the schema's dtype: True if its length and values
    pass (finite if float, inside the bounds); False sends it to the full check."""
    length, is_float = spec.length, spec.native.kind == "f"
    has_min, has_max = spec.min is not None, spec.max is not None
    lo = spec.min if has_min else -_FMAX
    hi = spec.max if has_max else _FMAX
    if not (is_float or has_min or has_max):
        return lambda arr: length is None or arr.size == length

    lo, hi = float(lo), float(hi)

    def valid(arr):
        size = arr.size
        if length is not None and size != length:
            return False
        if not size:
            return True
        if size > SMALL_ARRAY:  # one compiled pass; NaN fails the comparisons
            return kernels().within(arr, lo, hi)
        values = arr.tolist()  # plain Python is faster than numpy calls here
        # A sum of floats is finite only if every value is (a float64 sum can also
        # overflow: that array just takes the full check).
        if is_float and not math.isfinite(sum(values)):
            return False
        return (not has_min or lo <= min(values)) and (not has_max or max(values) <= hi)

    return valid


def _quick_check(spec) -> Callable[[Any], bool]:
    """A predicate that is True only for a value the full check would take unchanged
    (exact type, in range); anything else, valid or not, gets the full check. For the
    fields that are not scalars: :func:`_quick_test` writes a scalar's check out."""
    if isinstance(spec, Array):
        dtype, optional, valid = spec.native, spec.optional, _valid_values(spec)

        def accepts(value):
            if type(value) is not np.ndarray or value.ndim != 1 or value.dtype != dtype:
                return False
            if not valid(value):
                return False
            if value.base is None:  # setflags costs half of flags.writeable = False
                value.setflags(write=False)
            return True

    elif isinstance(spec, Mapping):
        optional = spec.optional

        def accepts(value):
            return type(value) is dict

    elif isinstance(spec, Blob):
        optional, length = spec.optional, spec.length

        def accepts(value):
            return type(value) is bytes and len(value) == length

    elif isinstance(spec, BlobList):
        optional = spec.optional

        def accepts(value):
            return type(value) is list and all(type(v) is bytes for v in value)

    else:
        optional = spec.optional

        def accepts(value):
            return type(value) is list and all(type(v) is str for v in value)

    if optional:
        return lambda value: value is None or accepts(value)
    return accepts


def _to_wire(spec) -> Callable[[np.ndarray], bytes] | None:
    """How a field's value goes on the wire: None for a value msgpack takes as it is,
    else array → little-endian bytes (no conversion on a little-endian machine)."""
    if not isinstance(spec, Array):
        return None
    if spec.wire.isnative:
        return np.ndarray.tobytes
    return lambda arr: arr.astype(spec.wire).tobytes()


def _leader(leaders: dict[str, str], name: str, spec) -> str | None:
    """The field whose length ``name`` must share (the first of its group), if any;
    ``leaders`` collects the first field of each group."""
    group = getattr(spec, "group", None)
    if group is None:
        return None
    leader = leaders.setdefault(group, name)
    return None if leader == name else leader


def _empty(dtype: str) -> Callable[[], np.ndarray]:
    """A ``default_factory`` of one shared empty array: read-only, like every message
    array, so sharing it is safe and saves an allocation per message."""
    empty = np.frombuffer(b"", np.dtype(dtype).newbyteorder("="))
    return lambda: empty


class _Factory:
    """The default of a field with a ``default_factory`` in a :func:`frozen` signature."""

    def __repr__(self) -> str:
        return "<factory>"


_FACTORY = _Factory()


def frozen(cls=None, *, eq: bool = False):
    """``@dataclass(frozen=True, eq=eq)``, with an ``__init__`` that fills the instance's
    ``__dict__`` directly. The frozen dataclass's own ``__init__`` sets each field through
    ``object.__setattr__``, a call per field: half of building a small message, and the loop
    builds several each step. Same signature, defaults and ``__post_init__`` call."""
    if cls is None:
        return lambda cls: frozen(cls, eq=eq)
    cls = dataclass(frozen=True, eq=eq)(cls)
    params, body, ns = [], ["    d = self.__dict__"], {"FACTORY": _FACTORY}
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        if f.default is not dataclasses.MISSING:
            ns[f"default_{f.name}"] = f.default
            params.append(f"{f.name}=default_{f.name}")
        elif f.default_factory is not dataclasses.MISSING:
            ns[f"factory_{f.name}"] = f.default_factory
            params.append(f"{f.name}=FACTORY")
            body.append(f"    if {f.name} is FACTORY: {f.name} = factory_{f.name}()")
        else:
            params.append(f.name)
        body.append(f"    d[{f.name!r}] = {f.name}")
    if hasattr(cls, "__post_init__"):
        body.append("    self.__post_init__()")
    source = "\n".join([f"def __init__(self, {', '.join(params)}):", *body])
    exec(compile(source, f"<{cls.__name__}.__init__>", "exec"), ns)
    init = ns["__init__"]
    init.__qualname__ = f"{cls.__name__}.__init__"
    cls.__init__ = init
    return cls


_PER_THREAD = threading.local()  # msgpack encoders per thread: reused, never shared


# --------------------------------------------------------------------------- base


class Message:
    """Base of every wire message: schema-driven encode, decode and validation.

    Subclasses are frozen dataclasses declaring ``SCHEMA`` (field name → spec).
    Construction validates and normalises (arrays to their schema dtype), so a
    message that exists is a valid one, whether built locally or decoded.
    """

    SCHEMA: ClassVar[dict[str, Scalar | Array | Mapping | StrList | Blob | BlobList]]

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        cls._KNOWN = frozenset(cls.SCHEMA) | {"v"}
        for name, function in _straight_line(cls).items():
            setattr(cls, name, function)

    def __post_init__(self):
        if not self._accepted_at_once():
            self._validate_fields()
        self._check()

    def _accepted_at_once(self) -> bool:
        """The quick path of validation: True if every field already has its schema type
        and passes its checks, so nothing needs converting. False sends the message to
        :meth:`_validate_fields`, which converts what it can and names what is wrong.
        (Written out per class by :func:`_straight_line`.)"""
        raise NotImplementedError

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
            elif isinstance(spec, Blob):
                if not isinstance(value, bytes) or len(value) != spec.length:
                    raise ProtocolError("type", f"{name} must be {spec.length} bytes")
            elif isinstance(spec, BlobList):
                if not isinstance(value, list) or not all(isinstance(v, bytes) for v in value):
                    raise ProtocolError("type", f"{name} must be a list of bytes")
            elif not isinstance(value, dict):
                raise ProtocolError("type", f"{name} must be a map")

    def _check(self) -> None:
        """Cross-field rules; subclasses override."""

    def to_dict(self) -> dict[str, Any]:
        """The msgpack-ready map: arrays as little-endian bytes, ``v`` added, absent
        optional fields left out. (Written out per class by :func:`_straight_line`.)"""
        raise NotImplementedError

    def encode(self) -> bytes:
        """This message as msgpack bytes, as it goes on the bus. Any thread may call it
        (each packs with a ``Packer`` of its own)."""
        try:
            pack = _PER_THREAD.pack
        except AttributeError:  # this thread's first message (packb builds a Packer per call)
            pack = _PER_THREAD.pack = msgpack.Packer(use_bin_type=True).pack
        return pack(self.to_dict())

    @classmethod
    def decode(cls, raw: bytes | bytearray | memoryview):
        """Parse and validate ``raw``; raise :class:`ProtocolError` if it is not a ``cls``."""
        data = unpack_map(raw)
        return cls.from_dict(data)

    @classmethod
    def from_dict(cls, data: dict[str, Any]):
        """Validate a decoded map. The fast path fills a bare instance (the dataclass
        ``__init__`` costs more than the checks of a small message): arrays viewed
        straight from their bytes, so only their values need checking, and the other
        fields through the constructor's quick checks. Anything else takes the full
        path, through the constructor, which names what is wrong. (Written out per class
        by :func:`_straight_line`.)"""
        raise NotImplementedError

    @classmethod
    def _refuse_version_or_fields(cls, data: dict[str, Any]) -> None:
        """Raise :class:`ProtocolError` for a map of another version or with unknown fields."""
        version = data.get("v")
        if type(version) is not int or version not in READ_VERSIONS:  # True, 2.0 are not 2
            raise ProtocolError("version", f"v must be one of {READ_VERSIONS}, got {version!r}")
        unknown = sorted(set(data) - cls._KNOWN)
        raise ProtocolError("unknown", f"{cls.__name__} has no field(s) {unknown}")

    @classmethod
    def _from_dict_in_full(cls, data: dict[str, Any]):
        values = {}
        for name, spec in cls.SCHEMA.items():
            if name not in data:
                if not spec.optional:
                    raise ProtocolError("missing", f"{cls.__name__}.{name} is missing")
                values[name] = None
                continue
            value = data[name]
            if isinstance(spec, Array) and not (value is None and spec.optional):
                value = _decode_array(name, spec, value)  # nil: absent, as for a scalar
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


# ------------------------------------------------------------------- straight-line paths


def _straight_line(cls) -> dict[str, Callable]:
    """``_accepted_at_once``, ``from_dict`` and ``to_dict`` of a message class, written out
    field by field from its ``SCHEMA`` and compiled once (as :mod:`dataclasses` writes
    ``__init__``): a loop over the schema costs more than the checks of a small message,
    and these run for every message of the loop."""
    ns: dict[str, Any] = {
        "frombuffer": np.frombuffer,
        "new": object.__new__,
        "READ_VERSIONS": READ_VERSIONS,
        "KNOWN": cls._KNOWN,
        "SCHEMA_VERSION": SCHEMA_VERSION,
    }
    names = list(cls.SCHEMA)
    leaders: dict[str, str] = {}  # group → its first field
    accept, decode, fill, first, encode = [], [], [], ["'v': SCHEMA_VERSION"], []
    typed = []  # the typed decode's fields (_typed_decode): arrays viewed and checked
    general = "return cls.from_dict(unpack_map(raw))"
    for i, (name, spec) in enumerate(cls.SCHEMA.items()):
        v, key = f"v{i}", repr(name)
        test = _quick_test(spec, v, i, ns)
        leader = _leader(leaders, name, spec)
        # a grouped array has its group's first array's length (checked before it)
        j = None if leader is None else names.index(leader)
        same = None if j is None else f"{v} is not None and (v{j} is None or v{j}.size != {v}.size)"
        accept += [f"    {v} = d[{key}]", f"    if not ({test}): return False"]
        decode.append(f"    {v} = data.get({key})")
        typed.append(f"    {v} = s.{name}")
        if isinstance(spec, Array) and spec.wire.isnative:
            # viewed from its bytes, an array has the schema's dtype: only its values need
            # checking (on a big-endian machine arrays take the full path)
            ns[f"wire{i}"], ns[f"valid{i}"] = spec.wire, _valid_values(spec)
            decode += [
                f"    if type({v}) is bytes and not len({v}) % {spec.wire.itemsize}:",
                f"        {v} = frombuffer({v}, wire{i})",
                f"        if not valid{i}({v}): return cls._from_dict_in_full(data)",
                f"    elif {v} is not None:" if spec.optional else "    else:",
                "        return cls._from_dict_in_full(data)",
            ]
            # msgspec gave bytes (or None for an optional array left out)
            indent = "        " if spec.optional else "    "
            if spec.optional:
                typed.append(f"    if {v} is not None:")
            typed += [
                f"{indent}if len({v}) % {spec.wire.itemsize}: {general}",
                f"{indent}{v} = frombuffer({v}, wire{i})",
                f"{indent}if not valid{i}({v}): {general}",
            ]
        else:
            decode.append(f"    if not ({test}): return cls._from_dict_in_full(data)")
        if same:
            accept.append(f"    if {same}: return False")
            decode.append(f"    if {same}: return cls._from_dict_in_full(data)")
            typed.append(f"    if {same}: {general}")
        fill.append(f"    d[{key}] = {v}")
        to_wire = _to_wire(spec)
        if to_wire is not None:
            ns[f"to_wire{i}"] = to_wire
        if spec.optional:
            wired = v if to_wire is None else f"to_wire{i}({v})"
            encode += [f"    {v} = d[{key}]", f"    if {v} is not None: out[{key}] = {wired}"]
        elif not encode:  # the leading required fields (never None) go in the map's literal
            first.append(f"{key}: d[{key}]" if to_wire is None else f"{key}: to_wire{i}(d[{key}])")
        else:
            wired = f"d[{key}]" if to_wire is None else f"to_wire{i}(d[{key}])"
            encode.append(f"    out[{key}] = {wired}")
    source = "\n".join(
        [
            "def _accepted_at_once(self):",
            "    d = self.__dict__",
            *accept,
            "    return True",
            "def from_dict(cls, data):",
            "    version = data.get('v')",
            "    if type(version) is not int or version not in READ_VERSIONS"
            " or not data.keys() <= KNOWN:",
            "        cls._refuse_version_or_fields(data)",
            *decode,
            "    message = new(cls)",
            "    d = message.__dict__",
            *fill,
            "    message._check()",
            "    return message",
            "def to_dict(self):",
            "    d = self.__dict__",
            f"    out = {{{', '.join(first)}}}",
            *encode,
            "    return out",
        ]
    )
    exec(compile(source, f"<{cls.__name__} straight-line paths>", "exec"), ns)
    out = {}
    for name in ("_accepted_at_once", "from_dict", "to_dict"):
        function = ns[name]
        function.__qualname__ = f"{cls.__name__}.{name}"
        function.__doc__ = getattr(Message, name).__doc__
        out[name] = classmethod(function) if name == "from_dict" else function
    decode = _typed_decode(cls, ns, typed + fill, general)
    if decode is not None:
        out["decode"] = classmethod(decode)
        out["encode"] = _typed_encode
    return out


def _typed_encode(self) -> bytes:
    """``encode`` of a loop message: its map packed by msgspec (the same bytes as msgpack's,
    in about half the time). Only for messages of scalars and arrays, whose values are
    exact Python types once built: msgspec refuses a numpy scalar where msgpack takes it,
    and a free-form map may hold one."""
    try:
        pack = _PER_THREAD.typed_pack
    except AttributeError:  # this thread's first loop message
        pack = _PER_THREAD.typed_pack = msgspec.msgpack.Encoder().encode
    return pack(self.to_dict())


def _wire_struct(cls) -> type | None:
    """A ``msgspec.Struct`` of the map a ``cls`` is on the wire, that msgspec decodes and
    checks in C: scalars of their exact types inside their bounds (floats finite), arrays as
    ``bin``, no unknown field, every required one. None for a schema with fields other than
    scalars and native-order arrays (those classes are not the loop's)."""
    fields: list[tuple] = [("v", int)]
    for name, spec in cls.SCHEMA.items():
        if isinstance(spec, Scalar):
            kind = spec.kind
            if kind is float:  # bounds left open are ±_FMAX: NaN and infinities fail them
                lo = -_FMAX if spec.min is None else spec.min
                hi = _FMAX if spec.max is None else spec.max
                kind = Annotated[float, msgspec.Meta(ge=lo, le=hi)]
            elif kind is int and (spec.min is not None or spec.max is not None):
                kind = Annotated[int, msgspec.Meta(ge=spec.min, le=spec.max)]
        elif isinstance(spec, Array) and spec.wire.isnative:
            kind = bytes
        else:
            return None
        fields.append((name, kind | None, None) if spec.optional else (name, kind))
    return msgspec.defstruct(
        f"{cls.__name__}OnTheWire", fields, kw_only=True, forbid_unknown_fields=True
    )


def _typed_decode(cls, ns: dict, fields: list[str], general: str) -> Callable | None:
    """``decode`` of a loop message, written out from its schema: msgspec decodes the map
    and checks its scalars (:func:`_wire_struct`), then ``fields`` (written by
    :func:`_straight_line`) view the arrays from their bytes, check their values as
    :meth:`Message.from_dict` does, and fill the message. Anything msgspec or those checks
    refuse goes the general way (``general``: :func:`unpack_map`, :meth:`Message.from_dict`),
    which names what is wrong; so the two ways differ in speed only."""
    wire = _wire_struct(cls)
    if wire is None:
        return None
    ns.update(
        wire_decode=msgspec.msgpack.Decoder(wire).decode,
        WireFault=msgspec.MsgspecError,
        unpack_map=unpack_map,
        MAX_MESSAGE_BYTES=MAX_MESSAGE_BYTES,
    )
    lines = [
        "def decode(cls, raw):",
        "    if type(raw) is not bytes or len(raw) > MAX_MESSAGE_BYTES:",
        f"        {general}",
        "    try:",
        "        s = wire_decode(raw)",
        "    except (WireFault, ValueError):  # msgspec lets a key's bad UTF-8 through as such",
        f"        {general}",
        "    if s.v not in READ_VERSIONS:",
        f"        {general}",
        "    message = new(cls)",
        "    d = message.__dict__",
        *fields,
        "    message._check()",
        "    return message",
    ]
    exec(compile("\n".join(lines), f"<{cls.__name__} typed decode>", "exec"), ns)
    decode = ns["decode"]
    decode.__qualname__ = f"{cls.__name__}.decode"
    decode.__doc__ = Message.decode.__doc__
    return decode


def _quick_test(spec, v: str, i: int, ns: dict) -> str:
    """The quick check of the value named ``v`` as an expression: a scalar's written out,
    the rest a call of the predicate :func:`_quick_check` makes. Bounds left open in the
    schema are ``±_FMAX`` here, so one chained comparison also rejects NaN and infinities."""
    if not isinstance(spec, Scalar):
        ns[f"accepts{i}"] = _quick_check(spec)
        return f"accepts{i}({v})"
    kind = spec.kind
    if kind is float or kind is int:
        ns[f"lo{i}"] = -_FMAX if spec.min is None else spec.min
        ns[f"hi{i}"] = _FMAX if spec.max is None else spec.max
        test = f"type({v}) is {kind.__name__} and lo{i} <= {v} <= hi{i}"
    else:
        test = f"type({v}) is {kind.__name__}"
    return f"{v} is None or ({test})" if spec.optional else test


def unpack_map(raw: bytes | bytearray | memoryview) -> dict[str, Any]:
    """msgpack bytes → dict with str keys, or :class:`ProtocolError`."""
    if len(raw) > MAX_MESSAGE_BYTES:
        raise ProtocolError("not_msgpack", f"message of {len(raw)} bytes exceeds the limit")
    if type(raw) is not bytes:  # decoded arrays view the payload: it must be immutable
        raw = bytes(raw)
    try:
        data = msgpack.unpackb(raw, raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types
        raise ProtocolError("not_msgpack", f"undecodable payload ({type(exc).__name__})") from None
    if not isinstance(data, dict):
        raise ProtocolError("not_a_map", f"payload is a {type(data).__name__}, not a map")
    return data


_STEP = Scalar(int, min=0)
_RUN = Scalar(str)
_TIME = Scalar(float, min=0.0)
# Tolerance of window comparisons: times are products of integers and the period.
WINDOW_TOLERANCE_S = 1e-9
MODES = ("lockstep", "realtime")


@frozen(eq=True)
class StepWindow:
    """The run time that step ``step`` of run ``run`` covers: ``[t0_s, t1_s)``.

    The one place where a step becomes a time: every input carries its window, and
    every endpoint answers for that window (contract v2, docs/contract.md).
    """

    run: str
    step: int
    t0_s: float
    t1_s: float

    @classmethod
    def of(cls, run: str, step: int, period_s: float) -> StepWindow:
        """Step ``step`` of a run with period ``period_s``: ``[step·T, (step+1)·T)``.

        Parameters
        ----------
        run : str
            The run's id.
        step : int
            The step, from 0.
        period_s : float
            The run's period ``T``.
        """
        return cls(run, step, *cls.bounds_s(step, period_s))

    @staticmethod
    def bounds_s(step: int, period_s: float) -> tuple[float, float]:
        """``(t0_s, t1_s)`` of step ``step`` at period ``period_s`` (what :meth:`of`
        builds on; for checks that need the times alone).

        Parameters
        ----------
        step : int
            The step, from 0.
        period_s : float
            The run's period.
        """
        return step * period_s, (step + 1) * period_s

    @property
    def period_s(self) -> float:
        """The window's length, ``t1_s - t0_s``."""
        return self.t1_s - self.t0_s

    @property
    def stamp(self) -> dict:
        """The fields an input message takes from its window."""
        return {"step": self.step, "run": self.run, "t0_s": self.t0_s, "t1_s": self.t1_s}


def _check_window(message) -> None:
    if not message.t1_s > message.t0_s:
        raise ProtocolError("inconsistent", f"t1_s {message.t1_s} must follow t0_s {message.t0_s}")


# --------------------------------------------------------------------------- messages


@frozen
class MotorCommand(Message):
    """Hub → body: wheel speeds for one step's window (zeros at step 0)."""

    step: int
    run: str
    t0_s: float
    t1_s: float
    left_mps: float
    right_mps: float
    v_mps: float | None = None
    omega_rad_s: float | None = None

    SCHEMA = {
        "step": _STEP,
        "run": _RUN,
        "t0_s": _TIME,
        "t1_s": _TIME,
        "left_mps": Scalar(float),
        "right_mps": Scalar(float),
        "v_mps": Scalar(float, optional=True),
        "omega_rad_s": Scalar(float, optional=True),
    }

    _check = _check_window

    @classmethod
    def stop(cls, window: StepWindow) -> MotorCommand:
        """Both wheels stopped for ``window``."""
        return cls(**window.stamp, left_mps=0.0, right_mps=0.0, v_mps=0.0, omega_rad_s=0.0)

    @property
    def window(self) -> StepWindow:
        """The step window this command is for."""
        return StepWindow(self.run, self.step, self.t0_s, self.t1_s)


@frozen
class SensorReading(Message):
    """Body → hub: range finders, pose and contact at the end of a step."""

    step: int
    run: str
    t_s: float  # run time at which the reading was taken (<= the window's t1_s)
    ranges_m: np.ndarray
    pose: np.ndarray
    contact: bool
    age_s: float | None = None  # how old the reading was when the reply left (devices)

    SCHEMA = {
        "step": _STEP,
        "run": _RUN,
        "t_s": _TIME,
        "ranges_m": Array("<f4", min=0.0),
        "pose": Array("<f8", length=3),
        "contact": Scalar(bool),
        "age_s": Scalar(float, min=0.0, optional=True),
    }


@frozen
class Stimulation(Message):
    """Hub → culture: the pulses to deliver during a step (parallel arrays)."""

    step: int
    run: str
    t0_s: float
    t1_s: float
    channel: np.ndarray = field(default_factory=_empty("<u4"))
    amplitude_ua: np.ndarray = field(default_factory=_empty("<f4"))
    width_ms: np.ndarray = field(default_factory=_empty("<f4"))
    onset_ms: np.ndarray = field(default_factory=_empty("<f4"))

    SCHEMA = {
        "step": _STEP,
        "run": _RUN,
        "t0_s": _TIME,
        "t1_s": _TIME,
        "channel": Array("<u4", group="pulse"),
        "amplitude_ua": Array("<f4", group="pulse"),
        "width_ms": Array("<f4", group="pulse", min=0.0),
        "onset_ms": Array("<f4", group="pulse", min=0.0),
    }

    def _check(self):
        _check_window(self)
        onset = self.onset_ms
        if onset.size:
            last = max(onset.tolist()) if onset.size <= SMALL_ARRAY else float(onset.max())
            window_ms = (self.t1_s - self.t0_s) * 1e3
            if last >= window_ms * (1 - 1e-9):  # the window's length carries rounding
                raise ProtocolError(
                    "range", f"onset_ms {last} lies outside the step's {window_ms} ms window"
                )

    @classmethod
    def none(cls, window: StepWindow) -> Stimulation:
        """No pulse during ``window``."""
        return cls(**window.stamp)

    @property
    def window(self) -> StepWindow:
        """The step window the pulses are for."""
        return StepWindow(self.run, self.step, self.t0_s, self.t1_s)

    @property
    def n_pulses(self) -> int:
        """How many pulses this message carries."""
        return int(self.channel.size)


@frozen
class SpikeBatch(Message):
    """Culture → hub: spikes fired in the window ``[t0_s, t1_s)``, sorted by time.

    A device may also carry spikes of earlier windows that reached it after it had answered
    them (``late_channel``, ``late_t_ms``: their true times, ms from ``t0_s``, so negative;
    contract v3): kept as data, never used by the loop's decoding.

    A device may stream a window's spikes as they come (contract v4): *parts*
    (``partial=True``) with the spikes read so far, then the window's batch with the rest.
    The step's spikes are all of them (:func:`merge_parts`); a part carries no late spikes.
    """

    step: int
    run: str
    t0_s: float
    t1_s: float
    channel: np.ndarray = field(default_factory=_empty("<u4"))
    t_ms: np.ndarray = field(default_factory=_empty("<f4"))
    late_channel: np.ndarray | None = None
    late_t_ms: np.ndarray | None = None
    partial: bool | None = None  # True: a part, more of this window to come; else None

    SCHEMA = {
        "step": _STEP,
        "run": _RUN,
        "t0_s": _TIME,
        "t1_s": _TIME,
        "channel": Array("<u4", group="spike"),
        "t_ms": Array("<f4", group="spike", min=0.0),
        "late_channel": Array("<u4", group="late", optional=True),
        "late_t_ms": Array("<f4", group="late", max=0.0, optional=True),
        "partial": Scalar(bool, optional=True),
    }

    @property
    def window(self) -> StepWindow:
        """The step window the spikes were fired in."""
        return StepWindow(self.run, self.step, self.t0_s, self.t1_s)

    def _check(self):
        if self.t1_s < self.t0_s:
            raise ProtocolError("inconsistent", f"t1_s {self.t1_s} precedes t0_s {self.t0_s}")
        if self.partial is not None and (not self.partial or self.late_channel is not None):
            raise ProtocolError(
                "inconsistent", "partial is true or absent, and a part carries no late spikes"
            )
        t_ms = self.t_ms
        if t_ms.size:
            if t_ms.size <= SMALL_ARRAY:  # values are finite here: sorted() is a full order
                values = t_ms.tolist()
                unsorted = values != sorted(values)
                last = values[-1]
            else:
                unsorted = not kernels().ascending(t_ms)
                last = float(t_ms[-1])
            if unsorted:
                raise ProtocolError("inconsistent", "t_ms must be sorted")
            window_ms = (self.t1_s - self.t0_s) * 1e3
            if last > window_ms * (1 + 1e-6) + 1e-3:
                raise ProtocolError(
                    "range", f"t_ms {t_ms[-1]} lies beyond the {window_ms} ms window"
                )


def merge_parts(parts: list[SpikeBatch], batch: SpikeBatch) -> SpikeBatch:
    """A window's spikes in one batch: its streamed ``parts`` and its final ``batch``
    (which keeps its late spikes), in time order.

    Parameters
    ----------
    parts : list of SpikeBatch
        The window's parts (``partial=True``) as they came; empty returns ``batch`` itself.
    batch : SpikeBatch
        The window's final batch.
    """
    if not parts:
        return batch
    every = [*parts, batch]
    t_ms = np.concatenate([b.t_ms for b in every])
    order = np.argsort(t_ms, kind="stable")
    channel = np.concatenate([b.channel for b in every])[order]
    return dataclasses.replace(batch, channel=channel, t_ms=t_ms[order])


@frozen
class Potentials(Message):
    """Sim culture → observers: a low-rate snapshot of membrane potentials."""

    step: int
    t_s: float
    v_mv: np.ndarray

    SCHEMA = {"step": _STEP, "t_s": Scalar(float, min=0.0), "v_mv": Array("<f4")}


@frozen
class Description(Message):
    """Reply of an endpoint's ``describe`` queryable: what it is and its geometry.

    A culture lists its channels (``channel``, ``x_um``, ``y_um``, and for
    simulated neurons ``cell_type``: :mod:`devices.culture`'s codes) and the limits of
    the stimulation it takes (``max_amplitude_ua``, ``max_width_ms``, ``max_pulse_hz``
    per channel; :mod:`hub.limits`). A body lists its range finders and drive geometry
    (``max_wheel_mps`` is its speed limit). A real device says it runs in real time only
    (``realtime_only``: a lockstep run is refused) and how long its own I/O cycle takes
    (``cycle_ms``: the hub warns when the period is shorter); a device culture that answers
    each window once it has passed says so (``answers_after_window``: in realtime its reply
    trails by a step). ``counters`` reports what the endpoint has dropped, by kind.
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
    max_amplitude_ua: float | None = None
    max_width_ms: float | None = None
    max_pulse_hz: float | None = None
    realtime_only: bool | None = None
    cycle_ms: float | None = None
    answers_after_window: bool | None = None
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
        "max_amplitude_ua": Scalar(float, min=0.0, optional=True),
        "max_width_ms": Scalar(float, min=0.0, optional=True),
        "max_pulse_hz": Scalar(float, min=0.0, optional=True),
        "realtime_only": Scalar(bool, optional=True),
        "cycle_ms": Scalar(float, min=0.0, optional=True),
        "answers_after_window": Scalar(bool, optional=True),
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
        """How many range finders a body has (a body's description only)."""
        return int(self.sensor_angles_rad.size)


@frozen
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


@frozen
class HubView(Message):
    """Hub → observers (``hub/view``), ``loop.view_hz`` times a second while anyone
    subscribes: what the loop carried since the last view, for a live display.

    Every spike the culture sent over the run time ``[from_s, to_s)`` (``spike_channel``,
    ``spike_t_ms``: run time in ms), every pulse the hub sent then (``pulse_channel``,
    ``pulse_t_ms``: onsets, run time in ms), the body's positions meanwhile (``trail_m``:
    x, y of each reading, in step order), and the newest reading (``sensors_step``,
    ``pose``, ``ranges_m``, ``contact``) and motor command (``left_mps``, ``right_mps``).
    ``step`` is the number of steps done. Telemetry: published with congestion control
    DROP, so an observer that cannot keep up misses views and never holds up the loop; a
    view missed leaves a gap between one view's ``to_s`` and the next one's ``from_s``.
    """

    step: int
    run: str
    from_s: float
    to_s: float
    spike_channel: np.ndarray = field(default_factory=_empty("<u4"))
    spike_t_ms: np.ndarray = field(default_factory=_empty("<f8"))
    pulse_channel: np.ndarray = field(default_factory=_empty("<u4"))
    pulse_t_ms: np.ndarray = field(default_factory=_empty("<f8"))
    trail_m: np.ndarray = field(default_factory=_empty("<f8"))
    sensors_step: int | None = None
    pose: np.ndarray | None = None
    ranges_m: np.ndarray | None = None
    contact: bool | None = None
    left_mps: float | None = None
    right_mps: float | None = None

    SCHEMA = {
        "step": _STEP,
        "run": _RUN,
        "from_s": Scalar(float, min=0.0),
        "to_s": Scalar(float, min=0.0),
        "spike_channel": Array("<u4", group="spike"),
        "spike_t_ms": Array("<f8", group="spike", min=0.0),
        "pulse_channel": Array("<u4", group="pulse"),
        "pulse_t_ms": Array("<f8", group="pulse", min=0.0),
        "trail_m": Array("<f8"),
        "sensors_step": Scalar(int, min=0, optional=True),
        "pose": Array("<f8", length=3, optional=True),
        "ranges_m": Array("<f4", min=0.0, optional=True),
        "contact": Scalar(bool, optional=True),
        "left_mps": Scalar(float, optional=True),
        "right_mps": Scalar(float, optional=True),
    }

    def _check(self):
        if self.to_s < self.from_s:
            raise ProtocolError("inconsistent", f"to_s {self.to_s} precedes from_s {self.from_s}")
        if self.trail_m.size % 2:
            raise ProtocolError("array", "trail_m must hold x, y pairs")


RUN_ID_CHARS = frozenset("0123456789abcdef")


def _check_run_id(run: str) -> None:
    if len(run) != 32 or not set(run) <= RUN_ID_CHARS:
        raise ProtocolError("range", f"run must be 32 lowercase hex characters, got {run!r}")


@frozen
class RunStart(Message):
    """Hub → one endpoint, as the payload of a query on its ``run`` key: a run begins.

    The run's timing is announced here once; every input then carries its window.
    ``key`` is this endpoint's secret for this run (inputs and replies are sealed with
    it, :mod:`hub.wire`); it travels only to the endpoint's own queryable.
    """

    run: str
    period_ms: float
    n_steps: int
    mode: str
    start_unix_s: float
    deadline_ms: float
    key: bytes
    seed: int | None = None

    SCHEMA = {
        "run": _RUN,
        "period_ms": Scalar(float, min=0.0),
        "n_steps": Scalar(int, min=1),
        "mode": Scalar(str),
        "start_unix_s": Scalar(float, min=0.0),
        "deadline_ms": Scalar(float, min=0.0),
        "key": Blob(16),
        "seed": Scalar(int, min=0, optional=True),
    }

    def _check(self):
        _check_run_id(self.run)
        if self.mode not in MODES:
            raise ProtocolError("range", f"mode must be one of {MODES}, got {self.mode!r}")
        if not self.period_ms > 0 or not self.deadline_ms > 0:
            raise ProtocolError("range", "period_ms and deadline_ms must be > 0")

    @property
    def period_s(self) -> float:
        """The run's period in s."""
        return self.period_ms / 1e3

    def window(self, step: int) -> StepWindow:
        """The window of ``step`` in this run."""
        return StepWindow.of(self.run, step, self.period_s)


@frozen
class RunEnd(Message):
    """Hub → one endpoint, on its ``run`` key: the run is over (the endpoint makes
    itself safe and becomes idle)."""

    run: str
    outcome: str

    SCHEMA = {"run": _RUN, "outcome": Scalar(str)}


@frozen
class RunHold(Message):
    """Hub → one endpoint, on its ``run`` key: the run is paused (``hold``: the endpoint
    makes itself safe now: wheels stopped, nothing delivered) or resumed (contract v3)."""

    run: str
    hold: bool

    SCHEMA = {"run": _RUN, "hold": Scalar(bool)}


@frozen
class RunReply(Message):
    """An endpoint's answer to ``RunStart``/``RunEnd``: taken, or refused and why."""

    ok: bool
    run: str
    reason: str = ""

    SCHEMA = {"ok": Scalar(bool), "run": _RUN, "reason": Scalar(str)}


def decode_run_request(raw: bytes) -> RunStart | RunEnd | RunHold:
    """The payload of a query on a ``run`` key: a ``RunStart``, ``RunEnd`` or ``RunHold``."""
    data = unpack_map(raw)
    if "period_ms" in data:
        return RunStart.from_dict(data)
    return (RunHold if "hold" in data else RunEnd).from_dict(data)


@frozen
class ObserverStart(Message):
    """Hub → the burst observer, on its ``run`` key (contract v3): a run begins. The hub
    forwards the culture's spikes to it (``ObservedSpikes`` on ``observer/bursts/spikes``)
    and it reports on ``observer/bursts/reports``, both sealed with ``key``, the
    observer's secret for this run. ``channel``: the culture's channel ids; ``burst``
    and ``network``: the keyword arguments of ``BurstParams`` and ``NetworkBurstParams``
    (``online.burst``, ``online.network``)."""

    run: str
    n_steps: int
    channel: np.ndarray
    key: bytes
    burst: dict = field(default_factory=dict)
    network: dict = field(default_factory=dict)

    SCHEMA = {
        "run": _RUN,
        "n_steps": Scalar(int, min=1),
        "channel": Array("<u4"),
        "key": Blob(16),
        "burst": Mapping(),
        "network": Mapping(),
    }

    def _check(self):
        _check_run_id(self.run)
        if not self.channel.size:
            raise ProtocolError("range", "channel must not be empty")


@frozen
class ObservedSpikes(Message):
    """Hub → the burst observer (``observer/bursts/spikes``, sealed with its run key): the
    culture's SpikeBatches the hub took since the last such message, each exactly as the
    culture sent it, in step order (what came in 50 ms of wall time in lockstep, in 30 ms
    in realtime). Telemetry: dropped rather than waited for; the observer counts the steps
    missing."""

    run: str
    batches: list

    SCHEMA = {"run": _RUN, "batches": BlobList()}


@frozen
class ObserverEnd(Message):
    """Hub → the burst observer, on its ``run`` key: the run is over after ``steps``
    steps; the observer answers with its final ``BurstReport`` once it has analysed the
    spikes of those steps (or given up waiting for them: ``missing_steps``)."""

    run: str
    steps: int

    SCHEMA = {"run": _RUN, "steps": Scalar(int, min=0)}


@frozen
class BurstReport(Message):
    """The burst observer → hub and live displays (``observer/bursts/reports``): what live
    burst detection found in the culture's spikes, up to ``until_ms`` of run time.

    ``nb_*``: the network bursts completed since the previous report (extent, core and
    number of channels, run time in ms, as ``hub.analysis.online.NetworkBurst``);
    ``onset_ms``: the start of a network burst under way (enough channels bursting
    now, not yet complete), for displays. ``bursts`` and ``network_bursts`` count from
    the run's start; ``dropped`` counts what the observer refused (a message not sealed
    with the run's key, a malformed SpikeBatch, another run's). ``final``: the answer to
    ``ObserverEnd``, everything still open completed as offline detection does at a
    record's end; its ``nb_*`` carry every network burst of the run, ``cpu_s`` the
    observer's CPU time over the run. ``missing_steps``: steps whose spikes never came
    (the link dropped them).
    """

    run: str
    until_ms: float
    bursts: int
    network_bursts: int
    dropped: int = 0
    nb_start_ms: np.ndarray = field(default_factory=_empty("<f8"))
    nb_end_ms: np.ndarray = field(default_factory=_empty("<f8"))
    nb_core_start_ms: np.ndarray = field(default_factory=_empty("<f8"))
    nb_core_end_ms: np.ndarray = field(default_factory=_empty("<f8"))
    nb_channels: np.ndarray = field(default_factory=_empty("<u4"))
    onset_ms: float | None = None
    final: bool = False
    missing_steps: int = 0
    cpu_s: float | None = None

    SCHEMA = {
        "run": _RUN,
        "until_ms": Scalar(float),
        "bursts": Scalar(int, min=0),
        "network_bursts": Scalar(int, min=0),
        "dropped": Scalar(int, min=0),
        "nb_start_ms": Array("<f8", group="nb"),
        "nb_end_ms": Array("<f8", group="nb"),
        "nb_core_start_ms": Array("<f8", group="nb"),
        "nb_core_end_ms": Array("<f8", group="nb"),
        "nb_channels": Array("<u4", group="nb"),
        "onset_ms": Scalar(float, optional=True),
        "final": Scalar(bool),
        "missing_steps": Scalar(int, min=0),
        "cpu_s": Scalar(float, min=0.0, optional=True),
    }

    def network_burst_rows(self) -> list[tuple[float, float, int, float, float]]:
        """The network bursts reported: (start_ms, end_ms, n_channels, core_start_ms,
        core_end_ms) each."""
        return list(
            zip(
                self.nb_start_ms.tolist(),
                self.nb_end_ms.tolist(),
                self.nb_channels.tolist(),
                self.nb_core_start_ms.tolist(),
                self.nb_core_end_ms.tolist(),
                strict=True,
            )
        )


CONTROL_COMMANDS = ("status", "pause", "resume", "stop", "config")


@frozen
class ControlRequest(Message):
    """Payload of a query on ``hub/control``."""

    cmd: str

    SCHEMA = {"cmd": Scalar(str)}

    def _check(self):
        if self.cmd not in CONTROL_COMMANDS:
            raise ProtocolError("range", f"cmd must be one of {CONTROL_COMMANDS}, got {self.cmd!r}")


@frozen
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
