"""Reading settings files: TOML only, ``extends``, and paths relative to the file naming them.

One rule for ``extends = "base.toml"`` (a path relative to the extending file), in every
kind of file (experiment, culture, world): the extending file is laid over its base —
tables merge key by key; arrays and values replace. One exception, for tables named
``params``: they belong to the ``scheme`` or ``kind`` beside them, so when the extending
file names another ``scheme``/``kind`` its ``params`` replace the base's whole; otherwise
they merge like any table. A table naming another ``scheme`` and no ``params`` has none: a
scheme's params mean nothing to another scheme (``somatotopic``'s ``sites_per_sensor`` to
``no_stimulation``). Another ``kind`` without ``params`` keeps the base's: the kinds of one
endpoint take the same ones (``culture.kind = "nest"`` reads ``sim_network``'s ``config``).
Likewise a table that names another ``shape`` (a world's arena: a circle's ``radius_m``
means nothing to a rectangle) is taken whole, not merged with the base's.

Path-valued keys are named by the caller as dotted patterns (``fnmatch``:
``"*.params.world"``); each is resolved when its file is read, relative to that file's
folder, so a file means the same wherever it is used from. Paths given on the command line
(overrides) are resolved relative to the current folder.
"""

from __future__ import annotations

import fnmatch
import os
import tomllib
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from settings.errors import ConfigError
from settings.overrides import get_dotted, parse_override, set_dotted

# Larger than any settings file; a bigger one is not meant as one (and is not read whole).
MAX_FILE_BYTES = 4 * 1024 * 1024
# Tables whose contents belong to the scheme or kind named beside them; a scheme's are not
# inherited by another scheme even when the extending file gives none.
OWNED_TABLE, OWNER_KEYS, SCHEME_KEY = "params", ("scheme", "kind"), "scheme"
# A table naming another of these is another thing: taken whole.
SHAPE_KEY = "shape"
# The checkout the code runs from (an editable install): its configs/ are the shipped ones.
PROJECT_ROOT = Path(__file__).resolve().parents[1]


def read_toml(path: str | Path, what: str = "config file") -> dict[str, Any]:
    """Read one TOML file, refusing anything that is not a non-empty TOML text file.

    Parameters
    ----------
    path : path
        The file.
    what : str
        What the file is, for the messages (``"world file"``).

    Raises
    ------
    ConfigError
        Naming the file: not found, a folder, too large, binary, not valid TOML, empty.
    """
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"{what} {path} not found{_shipped_hint(path)}")
    if path.is_dir():
        raise ConfigError(f"{what} {path} is a folder, not a TOML file")
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise ConfigError(f"{what} {path} is too large for a TOML file ({size:,} bytes)")
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{what} {path} cannot be read: {exc.strerror or exc}") from None
    try:
        if b"\x00" in raw:
            raise UnicodeDecodeError("utf-8", raw, 0, 1, "NUL byte")
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError(
            f"{what} {path} is not a text file (binary content); expected TOML"
        ) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{what} {path} is not valid TOML: {exc}") from None
    if not data:
        raise ConfigError(f"{what} {path} is empty (no settings in it)")
    return data


def _shipped_hint(path: Path) -> str:
    """For a relative path that names one of the project's own files (``configs/...``)
    from another folder: where that file is."""
    if path.is_absolute():
        return ""
    shipped = PROJECT_ROOT / path
    if not shipped.is_file():
        return ""
    return f" (relative to the current folder {Path.cwd()}); the project's own is {shipped}"


def load(path: str | Path, what: str = "config file", paths: Iterable[str] = ()) -> dict[str, Any]:
    """Read a settings file with its ``extends`` chain; path-valued keys made absolute.

    Parameters
    ----------
    path : path
        The file.
    what : str
        What the file is, for the messages.
    paths : iterable of str
        Dotted patterns of the keys that name files (``"*.params.config"``), resolved
        relative to the file that names them.

    Returns
    -------
    dict
        The merged contents (without ``extends``).
    """
    return _load(Path(path), what, tuple(paths), ())


def _load(path: Path, what: str, paths: tuple[str, ...], seen: tuple[Path, ...]) -> dict:
    data = read_toml(path, what)
    resolve_paths(data, paths, path.parent)
    base_name = data.pop("extends", None)
    if base_name is None:
        return data
    if not isinstance(base_name, str) or not base_name:
        raise ConfigError(f"{path}: extends must be a file name, got {base_name!r}")
    base_path = Path(_absolute(base_name, path.parent))
    here = path.resolve()
    if base_path.resolve() in seen + (here,):
        raise ConfigError(f"{path}: extends {base_name} makes a cycle")
    if not base_path.exists():  # named with the file that names it: in a chain, which one
        raise ConfigError(f"{path}: extends {base_name}: {what} {base_path} not found")
    return merge(_load(base_path, what, paths, seen + (here,)), data)


def merge(base: dict, over: dict) -> dict:
    """``over`` laid over ``base`` by the one rule of this module (see its docstring).

    Parameters
    ----------
    base, over : dict
        The base file's table and the extending file's; neither is changed.

    Returns
    -------
    dict
        A new table (values not merged are shared with the inputs, not copied).
    """
    if SHAPE_KEY in over and SHAPE_KEY in base and over[SHAPE_KEY] != base[SHAPE_KEY]:
        return dict(over)
    out = dict(base)
    new_owner = any(k in over and over[k] != base.get(k) for k in OWNER_KEYS)
    if SCHEME_KEY in over and over[SCHEME_KEY] != base.get(SCHEME_KEY):
        out.pop(OWNED_TABLE, None)
    for key, value in over.items():
        fresh = key == OWNED_TABLE and new_owner
        if isinstance(value, dict) and isinstance(out.get(key), dict) and not fresh:
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def resolve_paths(data: dict, patterns: Iterable[str], base_dir: Path, prefix: str = "") -> None:
    """Make every relative path at a key matching ``patterns`` absolute from ``base_dir``.

    Parameters
    ----------
    data : dict
        The table, changed in place; nested tables are walked.
    patterns : iterable of str
        Dotted ``fnmatch`` patterns of the path-valued keys (``"*.params.world"``).
    base_dir : Path
        The folder relative paths are taken from (the file's own); ``~`` is expanded.
    prefix : str
        Dotted path of ``data`` within the whole file, with its trailing dot.
    """
    patterns = tuple(patterns)
    if not patterns:
        return
    for key, value in data.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict):
            resolve_paths(value, patterns, base_dir, dotted + ".")
        elif (
            isinstance(value, str)
            and value
            and any(fnmatch.fnmatchcase(dotted, p) for p in patterns)
        ):
            data[key] = _absolute(value, base_dir)


def _absolute(name: str, base_dir: Path) -> str:
    # absolute even when the file was named relative to the current folder: a run's
    # manifest must name the same place when read from anywhere
    return os.path.abspath(os.path.join(base_dir, os.path.expanduser(name)))


def apply_overrides(
    data: dict, items: Iterable[str], paths: Iterable[str] = (), base_dir: Path | None = None
) -> dict:
    """Set each ``dotted.key=value`` item in ``data`` (in place; returned too).

    An item replaces what is at its key (a table given whole replaces the table).

    Parameters
    ----------
    data : dict
        The table.
    items : iterable of str
        ``dotted.key=value`` overrides, values parsed as TOML (:func:`parse_override`).
    paths : iterable of str
        Dotted patterns of the path-valued keys, as for :func:`load`.
    base_dir : Path, optional
        The folder relative paths in the items are taken from (default: the current one).

    Raises
    ------
    ConfigError
        An item not of the form ``dotted.key=value``, or one whose key runs through a
        value that is not a table.
    """
    patterns = tuple(paths)
    for item in items:
        key, value = parse_override(item)
        if patterns:
            holder: dict = {}
            set_dotted(holder, key, value)
            resolve_paths(holder, patterns, base_dir or Path.cwd())
            value = get_dotted(holder, key)
        set_dotted(data, key, value)
    return data
