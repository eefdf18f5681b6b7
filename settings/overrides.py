"""``dotted.key=value`` overrides: parsing (values typed as TOML) and setting them in a table."""

from __future__ import annotations

import json
import math
import numbers
import tomllib
from pathlib import PurePath
from typing import Any

from settings.errors import ConfigError


def parse_value(text: str) -> Any:
    """A TOML value (``5``, ``2.5``, ``true``, ``[1, 2]``, ``{a = 1}``, ``"x"``); text that
    is not one (``realtime``) is taken as a plain string."""
    try:
        return tomllib.loads(f"x = {text}")["x"]
    except tomllib.TOMLDecodeError:
        return text


def format_value(value: Any) -> str:
    """The TOML text of a value, for a ``key=value`` override (:func:`parse_value`'s
    inverse): numbers, booleans, strings, paths, lists and tables of them."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, numbers.Integral):  # numpy's integers too
        return repr(int(value))
    if isinstance(value, numbers.Real):  # numpy's floats too (repr: "np.float64(2.0)")
        value = float(value)
        if math.isnan(value):
            return "nan"
        return repr(value) if math.isfinite(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, str | PurePath):
        return json.dumps(str(value))  # a TOML basic string
    if isinstance(value, list | tuple):
        return "[" + ", ".join(format_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return (
            "{"
            + ", ".join(f"{json.dumps(str(k))} = {format_value(v)}" for k, v in value.items())
            + "}"
        )
    raise ConfigError(f"{value!r} ({type(value).__name__}) cannot be a setting's value")


def parse_override(item: str) -> tuple[str, Any]:
    """``"loop.period_ms=5"`` -> ``("loop.period_ms", 5)``."""
    key, sep, text = item.partition("=")
    key = key.strip()
    parts = key.split(".")
    if not sep or not key or not all(p.strip() for p in parts):
        raise ConfigError(f"override {item!r} must look like dotted.key=value")
    return key, parse_value(text.strip())


def set_dotted(data: dict, key: str, value: Any) -> None:
    """Set ``data[a][b][c] = value`` for ``key = "a.b.c"``, making tables on the way.

    Parameters
    ----------
    data : dict
        The table, changed in place.
    key : str
        Dotted key.
    value : Any
        What to put there; replaces what was there (a table too).

    Raises
    ------
    ConfigError
        A part of ``key`` before the last names a value that is not a table.
    """
    parts = key.split(".")
    node = data
    for i, part in enumerate(parts[:-1]):
        node = node.setdefault(part, {})
        if not isinstance(node, dict):
            where = ".".join(parts[: i + 1])
            raise ConfigError(f"override {key}: {where} is not a table")
    node[parts[-1]] = value


def get_dotted(data: dict, key: str, default: Any = None) -> Any:
    """``data[a][b][c]`` for ``key = "a.b.c"``, or ``default`` where a part is missing.

    Parameters
    ----------
    data : dict
        The table.
    key : str
        Dotted key.
    default : Any
        Returned when a part is missing or a part before the last is not a table.
    """
    node: Any = data
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            return default
        node = node[part]
    return node
