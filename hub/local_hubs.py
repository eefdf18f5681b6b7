"""Where the hubs running on this machine listen, by bus session.

``neuvision run`` gives its hub a free loopback port of its own (parallel runs stay apart),
so ``neuvision ctl`` and ``neuvision dashboard`` cannot guess it. While such a hub runs it
leaves a small file in a folder of this user's (:func:`folder`) saying its session, its
locators and its run folder; a command given a session and no address reads them
(:func:`find`). A file whose process has ended is stale and is removed when seen.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote

#: Overrides the folder (tests keep their hubs apart from a user's with it).
FOLDER_ENV = "NEUVISION_RUNTIME_DIR"


@dataclass(frozen=True)
class LocalHub:
    """One running hub, as its file says."""

    session: str
    locators: tuple[str, ...]
    run_dir: str
    pid: int


class AmbiguousSession(LookupError):
    """More than one hub on this machine runs the session asked for."""


def folder() -> Path:
    """This user's folder of hub files (made, private to the user, if missing; refused,
    with ``PermissionError``, if another user owns it or others may write in it):
    ``$NEUVISION_RUNTIME_DIR``, else ``$XDG_RUNTIME_DIR/neuvision``, else a folder in the
    system's temporary one named for the user."""
    path = os.environ.get(FOLDER_ENV)
    if not path:
        runtime = os.environ.get("XDG_RUNTIME_DIR")
        path = (
            Path(runtime) / "neuvision"
            if runtime
            else Path(tempfile.gettempdir()) / f"neuvision-{os.getuid()}"
        )
    path = Path(path)
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    st = path.stat()
    if st.st_uid != os.getuid() or st.st_mode & 0o022:
        # someone else's, or writable by others: what it says of hubs cannot be trusted
        raise PermissionError(f"{path} is not a folder of this user's alone")
    return path


def _prefix(session: str) -> str:
    return quote(session, safe="") + "--"


def reachable_here(locator: str) -> str:
    """``locator`` as this machine reaches it: a hub listening on every address
    (``tcp/0.0.0.0:7447``, ``tcp/[::]:7447``) is reached on loopback."""
    scheme, slash, rest = locator.partition("/")
    for anywhere, here in (("0.0.0.0:", "127.0.0.1:"), ("[::]:", "[::1]:")):
        if slash and rest.startswith(anywhere):
            return f"{scheme}/{here}{rest.removeprefix(anywhere)}"
    return locator


@contextlib.contextmanager
def announced(session: str, locators: list[str], run_dir: str | Path) -> Iterator[Path]:
    """Say, while the block runs, that a hub of this process listens on ``locators``
    for ``session``; the file is removed after. A folder that cannot be written leaves
    the hub unannounced (it runs all the same: ``--connect`` still finds it).

    Parameters
    ----------
    session : str
        The hub's bus session.
    locators : list of str
        Where it listens (``bus.listen``).
    run_dir : str or Path
        Its run folder (announced resolved).

    Yields
    ------
    Path or None
        The announcement's file, or None when it could not be written.
    """
    try:
        path = folder() / f"{_prefix(session)}{os.getpid()}-{uuid.uuid4().hex[:8]}.json"
        record = {
            "session": session,
            "locators": list(locators),
            "run_dir": str(Path(run_dir).resolve()),
        }
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(record | {"pid": os.getpid()}))
        tmp.replace(path)
    except OSError:
        yield None
        return
    try:
        yield path
    finally:
        path.unlink(missing_ok=True)


def running(session: str) -> list[LocalHub]:
    """The hubs of ``session`` running on this machine (stale files removed)."""
    try:
        paths = sorted(folder().glob(_prefix(session) + "*.json"))
    except OSError:
        return []
    hubs = []
    for path in paths:
        try:
            record = json.loads(path.read_text())
            hub = LocalHub(
                record["session"], tuple(record["locators"]), record["run_dir"], record["pid"]
            )
        except (OSError, ValueError, KeyError, TypeError):
            continue  # being written, or not one of ours
        if hub.session != session:
            continue
        if not _alive(hub.pid):
            path.unlink(missing_ok=True)
            continue
        hubs.append(hub)
    return hubs


def find(session: str) -> LocalHub | None:
    """The one hub of ``session`` running on this machine, or None if there is none.

    Raises
    ------
    AmbiguousSession
        Several run it: the message lists their locators and run folders.
    """
    hubs = running(session)
    if len(hubs) > 1:
        listed = "; ".join(f"{', '.join(h.locators)} ({h.run_dir})" for h in hubs)
        raise AmbiguousSession(
            f"{len(hubs)} hubs on this machine run session {session!r}: {listed}; "
            "give --connect with one of these addresses"
        )
    return hubs[0] if hubs else None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's process: alive, not ours to judge
    return True
