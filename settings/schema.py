"""Validating plain tables against frozen dataclasses, by dotted key.

A dataclass is the schema: its fields' types say what each key takes, their defaults are
the one place of each default, and ``field(metadata=bounds(...))`` adds limits. Unknown
keys are refused with a "did you mean"; every message starts with the dotted key.
Checks across fields belong in the dataclass's ``__post_init__`` (raising
:class:`ConfigError` naming keys from that dataclass); :func:`build` places them under the
prefix it was given.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import types
import typing
from collections.abc import Callable
from typing import Any

from settings.errors import ConfigError, under
from settings.files import apply_overrides


def bounds(
    *,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    choices: tuple | None = None,
    check: Callable[[str, Any], Any] | None = None,
    parse: Callable[[str, Any], Any] | None = None,
) -> dict:
    """Field metadata (``field(metadata=bounds(...))``) that :func:`coerce` checks.

    Parameters
    ----------
    gt, ge, lt, le : float, optional
        Limits of the value: greater than, at least, less than, at most.
    choices : tuple, optional
        The values allowed.
    check : callable, optional
        ``check(dotted, value) -> value``, run after the type and limits; raises
        :class:`ConfigError`.
    parse : callable, optional
        ``parse(dotted, raw) -> value``, run instead of the type check (for values with
        their own message); the limits and ``check`` still apply.
    """
    return {
        "gt": gt,
        "ge": ge,
        "lt": lt,
        "le": le,
        "choices": choices,
        "check": check,
        "parse": parse,
    }


def known_keys(cls) -> list[str]:
    """The keys a table built as dataclass ``cls`` (:func:`build`) may have."""
    return [f.name for f in dataclasses.fields(cls) if not f.metadata.get("internal")]


def check_known(data: dict, known: list[str], prefix: str = "") -> None:
    """Refuse a table with a key that is not known.

    Parameters
    ----------
    data : dict
        The table.
    known : list of str
        The keys it may have (:func:`known_keys`).
    prefix : str
        Dotted path of ``data`` within the whole file, put before the key in the message.

    Raises
    ------
    ConfigError
        Naming the first unknown key, with a close match if there is one, and the known keys.
    """
    for key in data:
        if key not in known:
            hint = difflib.get_close_matches(str(key), known, n=1)
            extra = f" (did you mean {hint[0]}?)" if hint else ""
            raise ConfigError(f"{prefix}{key} is not a known key{extra}; known: {', '.join(known)}")


def build(cls: type, data: Any, prefix: str = "") -> Any:
    """Validate a nested table against dataclass ``cls`` and build it.

    Parameters
    ----------
    cls : dataclass type
    data : dict
        Plain values as read from TOML; absent keys take the field defaults.
    prefix : str
        Dotted path of ``data`` within the whole file (``"culture.params."``), put before
        every key named in an error.

    Raises
    ------
    ConfigError
        ``<prefix><key> ...``: unknown key (with a close match), wrong type, out of bounds.
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{prefix.rstrip('.')} must be a table, got {data!r}")
    fields = {f.name: f for f in dataclasses.fields(cls) if not f.metadata.get("internal")}
    check_known(data, list(fields), prefix)
    hints = typing.get_type_hints(cls)
    values = {}
    for name, f in fields.items():
        if name not in data:
            continue
        hint = hints[name]
        value = data[name]
        if dataclasses.is_dataclass(hint) and isinstance(value, dict):
            # a partial table keeps the other values of this field's default (which may
            # differ from the nested class's own defaults)
            base = _default(f)
            if base is not None:
                value = {**_shallow(base), **value}
        values[name] = coerce(prefix + name, hint, value, f.metadata)
    try:
        return cls(**values)
    except ConfigError as exc:
        raise under(prefix, exc) from None


def _default(f: dataclasses.Field) -> Any:
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    if f.default is not dataclasses.MISSING:
        return f.default
    return None


def _shallow(obj: Any) -> dict:
    return {
        f.name: getattr(obj, f.name)
        for f in dataclasses.fields(obj)
        if not f.metadata.get("internal") and getattr(obj, f.name) is not None
    }


def coerce(dotted: str, hint: Any, value: Any, meta: dict | None = None) -> Any:
    """Check one value against a type (and ``meta`` from :func:`bounds`); return it typed.

    Types: bool, int, float (finite), str, dict, ``X | None``, ``tuple[X, ...]``,
    ``tuple[X, Y]`` and dataclasses (a table).

    Parameters
    ----------
    dotted : str
        The value's dotted key, for the messages.
    hint : type
        The field's type annotation (resolved, not a string).
    value : Any
        As read from TOML; an int is taken for a float, a string for ``tuple[str, ...]``.
    meta : dict, optional
        The field's metadata (:func:`bounds`).

    Raises
    ------
    ConfigError
        ``<dotted> ...``: wrong type, not finite, out of bounds, not one of the choices.
    """
    meta = meta or {}
    if meta.get("parse") is not None:
        return _limits(dotted, meta["parse"](dotted, value), meta)
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if isinstance(hint, types.UnionType) or origin is typing.Union:
        inner = [a for a in args if a is not type(None)]
        if value is None and len(inner) < len(args):
            return None
        return coerce(dotted, inner[0], value, meta)
    if dataclasses.is_dataclass(hint):
        if isinstance(value, hint):
            return value
        return build(hint, value, dotted + ".")
    if origin is tuple:
        value = _tuple(dotted, args, value)
    elif hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{dotted} must be true or false, got {value!r}")
    elif hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{dotted} must be an integer, got {value!r}")
    elif hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{dotted} must be a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"{dotted} must be finite, got {value}")
    elif hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{dotted} must be a string, got {value!r}")
    elif hint is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{dotted} must be a table, got {value!r}")
    elif isinstance(hint, type) and not isinstance(value, hint):
        raise ConfigError(f"{dotted} must be a {hint.__name__}, got {value!r}")
    return _limits(dotted, value, meta)


def _tuple(dotted: str, args: tuple, value: Any) -> tuple:
    if len(args) == 2 and args[1] is Ellipsis:
        if isinstance(value, str) and args[0] is str:
            value = [value]
        kind = {str: "strings", int: "integers", float: "numbers"}.get(args[0], "values")
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{dotted} must be a list of {kind}, got {value!r}")
        try:
            return tuple(coerce(f"{dotted}[{i}]", args[0], v) for i, v in enumerate(value))
        except ConfigError:
            raise ConfigError(f"{dotted} must be a list of {kind}, got {value!r}") from None
    if not isinstance(value, list | tuple) or len(value) != len(args):
        raise ConfigError(f"{dotted} must be a list of {len(args)} numbers, got {value!r}")
    pairs = enumerate(zip(value, args, strict=True))
    return tuple(coerce(f"{dotted}[{i}]", a, v) for i, (v, a) in pairs)


def _limits(dotted: str, value: Any, meta: dict) -> Any:
    for op, ok in (
        ("gt", lambda v, b: v > b),
        ("ge", lambda v, b: v >= b),
        ("lt", lambda v, b: v < b),
        ("le", lambda v, b: v <= b),
    ):
        limit = meta.get(op)
        if limit is not None and not ok(value, limit):
            sign = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}[op]
            raise ConfigError(f"{dotted} must be {sign} {limit}, got {value}")
    choices = meta.get("choices")
    if choices and value not in choices:
        raise ConfigError(f"{dotted} must be one of {', '.join(map(str, choices))}; got {value!r}")
    check = meta.get("check")
    if check is not None:
        value = check(dotted, value)
    return value


def to_plain(obj: Any) -> Any:
    """Nested plain values (dicts, lists, scalars) of a config: TOML/JSON-ready, the inverse
    of :func:`build`. ``None`` fields (absent in a file) and internal fields are left out."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {
            f.name: to_plain(getattr(obj, f.name))
            for f in dataclasses.fields(obj)
            if not f.metadata.get("internal") and getattr(obj, f.name) is not None
        }
    if isinstance(obj, dict):
        return {k: to_plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_plain(v) for v in obj]
    return obj


def with_overrides(obj: Any, items: list[str], prefix: str = "") -> Any:
    """A copy of config dataclass ``obj`` with ``dotted.key=value`` items applied, validated.

    ``with_overrides(network_cfg, ["noise.sd=3.5"])``.

    Parameters
    ----------
    obj : dataclass
        The config; not changed.
    items : list of str
        ``dotted.key=value`` overrides, keys relative to ``obj``.
    prefix : str
        Dotted path of ``obj`` within the whole file, put before the key in a message.

    Raises
    ------
    ConfigError
        ``<prefix><key> ...``: a malformed item, or a value :func:`build` refuses.
    """
    return build(type(obj), apply_overrides(to_plain(obj), items), prefix)
