"""The run record: an append-only file of every message, and the run manifest.

A run folder holds ``manifest.json`` (config, seed, versions, hosts, start,
end, outcome, timing) and ``record.nvrec``: a stream of msgpack frames, the
first a header map, then one list per message or event::

    [t_wall_ns, direction, key, payload_bytes]   # a message the hub sent or received
    [t_wall_ns, "ev", name, {details}]           # something the hub noticed or did

where direction is ``tx`` (sent), ``rx`` (received and used by the loop),
``late`` (valid, but arrived after its deadline: real data the loop did not
use), ``part`` (a part of a step's spikes that a device streamed before its batch: the
loop uses it with that batch), ``drop`` (received and dropped: malformed, stale, duplicate, future,
foreign) or ``final`` (the body's answer to the hub's final stop, after the run's last
step: the proof the stop was applied, not the run's data).

A dropped payload is anyone's to send (a stranger can fill the disk), so it is stored
capped (format version 2): its payload field is a map, not bytes::

    {"head": first DROP_HEAD_BYTES bytes, "n_bytes": its length,
     "blake2b": 16-byte BLAKE2b digest of the whole payload}

read back as a :class:`Dropped`, never as a message. What the drops stored take in a run
is bounded (``drop_budget_bytes``); past it a drop is only counted, and the recorder
writes a ``drops_not_stored`` event (``n``, ``n_bytes``) at close. Version 1 records
(drops in full, as bytes) read as before.

The writer flushes at least every ``flush_s`` (≤ 1 s), so a run killed at any
moment leaves a record readable up to its last flush; the reader returns
everything up to a truncated or damaged tail without error.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import hashlib
import json
import os
import platform
import socket
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from hub.analysis.output import write_whole
from hub.protocol import (
    Description,
    MotorCommand,
    ProtocolError,
    SensorReading,
    SpikeBatch,
    Stimulation,
)
from hub.wire import MAX_MESSAGE_BYTES

RECORD_FILE = "record.nvrec"
MANIFEST_FILE = "manifest.json"
#: room kept in a run folder, while the run goes on, for the manifest that ends it
RESERVE_FILE, RESERVE_BYTES = ".room-for-the-manifest", 1 << 20
FORMAT = "neuvision-record"
FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)
# "final": the body's answer to the hub's final stop, after the run's last step
DIRECTIONS = ("tx", "rx", "late", "part", "drop", "ev", "final")
# What the analysis reads as the culture's and body's real output.
DATA_DIRECTIONS = ("rx", "late", "part")
_STEP_DIRECTIONS = frozenset(("tx", "rx", "late"))  # one a step and key: inputs, replies
WRITE_BUFFER_BYTES = 1 << 20
HELD_FRAMES = 1024  # frames held at most before they are written
# Dropped payloads: the first bytes kept, and what all drops stored may take per run
# (head + digest + key + framing, counted per drop).
DROP_HEAD_BYTES = 64
DROP_DIGEST_BYTES = 16
DROP_BUDGET_BYTES = 4 << 20
_DROP_FRAME_OVERHEAD_BYTES = 40  # time, direction, map keys and msgpack headers


def utc_now() -> str:
    """The time now, UTC, in ISO 8601 to the millisecond (the manifest's times)."""
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds")


class OutputError(Exception):
    """An output folder that cannot be made or written in: the message names the option or
    key that gave it, the path and why (a user's input: one line, exit status 3)."""


def make_output_folder(path: str | Path, what: str) -> Path:
    """Make the folder ``path`` (and its parents) unless it is there; return it.

    Parameters
    ----------
    path : str or Path
        The folder.
    what : str
        Where the path came from, for the error (``--out``, ``experiment.runs_dir``).

    Raises
    ------
    OutputError
        It cannot be made (a file in the way, a parent missing on a read-only file system)
        or written in.
    """
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{what}: cannot make folder {path}: {_why_not(path, exc)}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        read_only = os.statvfs(path).f_flag & os.ST_RDONLY
        why = "a read-only file system" if read_only else "permission denied"
        raise OutputError(f"{what}: cannot write in folder {path}: {why}")
    return path


def _why_not(path: Path, exc: OSError) -> str:
    for p in (path, *path.parents):  # the nearest thing there: a file in the way?
        if p.exists() or p.is_symlink():
            if not p.is_dir():
                return f"{p} is a file, not a folder"
            break
    return exc.strerror or str(exc)


def new_run_dir(runs_dir: str | Path, name: str, what: str = "experiment.runs_dir") -> Path:
    """Create ``runs_dir/<UTC time>-<name>[-n]`` and return it.

    Parameters
    ----------
    runs_dir : str or Path
        Where run folders go (made if missing).
    name : str
        The run's name, after the time (``-1``, ``-2``... added when one is taken).
    what : str
        Where ``runs_dir`` came from, for the error.

    Raises
    ------
    OutputError
        ``runs_dir`` cannot be made or written in.
    FileExistsError
        The time and name are taken a thousand times over.
    """
    make_output_folder(runs_dir, what)
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y%m%d-%H%M%S")
    base = Path(runs_dir) / f"{stamp}-{name}"
    for n in range(1000):
        path = base if n == 0 else base.with_name(f"{base.name}-{n}")
        try:
            path.mkdir(parents=True)
            return path
        except FileExistsError:
            continue
    raise FileExistsError(f"cannot create a run folder under {runs_dir}")


def versions() -> dict[str, str]:
    """Versions of Python and of the packages a run's results depend on."""
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": platform.python_version()}
    for pkg in ("neuvision", "eclipse-zenoh", "numpy", "numba", "pymunk", "msgpack"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "absent"
    return out


def host() -> dict[str, Any]:
    """Where this process runs, and which process it is (``pid`` and, on Linux, when it
    started: a pid alone may be reused). :func:`read_run` uses them to tell a run still
    going from one whose hub ended without closing it."""
    out: dict[str, Any] = {"hostname": socket.gethostname(), "platform": platform.platform()}
    out["pid"] = os.getpid()
    started = _process_start(out["pid"])
    if started is not None:
        out["pid_start_ticks"] = started
    return out


def _process_start(pid: int) -> int | None:
    """When process ``pid`` started, in clock ticks since boot (Linux); None if unknown."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return int(f.read().rpartition(")")[2].split()[19])
    except (OSError, ValueError, IndexError):
        return None


#: the outcome a run reads as when its manifest says "running" and its hub is gone
UNFINISHED = "unfinished"


def hub_gone(manifest: dict[str, Any]) -> bool:
    """Whether a run whose manifest still says "running" has lost its hub: the hub's
    process, on this host, no longer exists (killed outright, crashed in native code, or
    the host restarted). A run written on another host is not judged (False)."""
    hub = manifest.get("hosts", {}).get("hub", {})
    pid = hub.get("pid")
    if manifest.get("outcome") != "running" or not isinstance(pid, int):
        return False
    if hub.get("hostname") != socket.gethostname():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        pass  # exists, another user's
    started = hub.get("pid_start_ticks")
    return started is not None and _process_start(pid) not in (None, started)


def experiment_text(source: str | Path | None) -> str | None:
    """The experiment file's text as the run starts, for the manifest (``config_text``):
    the file may be edited or gone by the time the run is read. None without a file, or
    if it cannot be read now (the resolved ``config`` beside it still says what ran)."""
    if not source:
        return None
    try:
        return Path(source).read_text()
    except (OSError, UnicodeDecodeError):
        return None


def write_manifest(run_dir: Path, manifest: dict[str, Any]) -> None:
    """Write ``manifest.json`` atomically (a reader never sees half a file; a write that
    fails, on a full disk, leaves the manifest as it was and no temporary file).

    While the run goes on (outcome ``"running"``) a file of :data:`RESERVE_BYTES` is kept
    beside it (:data:`RESERVE_FILE`): a disk that fills during the run still takes the
    manifest that says how it ended (the reserve given up for it), not a manifest left
    "running" with the cause nowhere in the folder. A final manifest written removes it.

    Parameters
    ----------
    run_dir : Path
        The run's folder.
    manifest : dict
        The manifest; numpy scalars and arrays in it are written as plain JSON.
    """
    text = json.dumps(manifest, indent=2, default=_json_default)
    reserve = run_dir / RESERVE_FILE
    running = manifest.get("outcome") == "running"
    if running and not reserve.exists():
        with contextlib.suppress(OSError):  # no room even for it: the run says so soon
            write_whole(reserve, bytes(RESERVE_BYTES))
    try:
        write_whole(run_dir / MANIFEST_FILE, text)
    except OSError as exc:
        if exc.errno != errno.ENOSPC or running or not reserve.exists():
            raise
        reserve.unlink()
        write_whole(run_dir / MANIFEST_FILE, text)
    if not running:
        with contextlib.suppress(OSError):
            reserve.unlink(missing_ok=True)


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


class RecordError(OSError):
    """The record could not be written (its disk full, its folder gone): the message names
    the file and the system's reason."""


class Recorder:
    """Appends frames to ``record.nvrec``, flushing at least every ``flush_s``.

    A write that fails raises :class:`RecordError`.

    Frames are held, and packed and written by :meth:`tick` (or once HELD_FRAMES are
    held), so that recording a message costs the loop's critical path one append.

    Parameters
    ----------
    run_dir : str or Path
        The run's folder; the record is appended to its ``record.nvrec``.
    flush_s : float
        Longest time between flushes, in s: it bounds what a crash may lose.
    drop_budget_bytes : int
        What the dropped payloads stored may take in all; past it drops are only counted.
    """

    def __init__(
        self,
        run_dir: str | Path,
        *,
        flush_s: float = 0.5,
        drop_budget_bytes: int = DROP_BUDGET_BYTES,
    ):
        self.path = Path(run_dir) / RECORD_FILE
        self.flush_s = flush_s
        self.drop_budget_bytes = drop_budget_bytes
        self.drop_bytes_stored = 0  # what the capped drops stored take (estimate)
        self.drops_not_stored = 0  # drops past the budget: counted only
        self.drop_bytes_not_stored = 0  # their payloads' total length
        # Written in large blocks (a write call per few messages costs the loop); the
        # flush every ``flush_s`` bounds what a crash can lose.
        self._file = open(self.path, "ab", buffering=WRITE_BUFFER_BYTES)
        self._pack = msgpack.Packer(use_bin_type=True).pack
        self._last_flush = time.monotonic()
        self.n_frames = 0
        self._held: list = []
        self._write(
            {"format": FORMAT, "v": FORMAT_VERSION, "t0_wall_ns": time.time_ns(), "host": host()}
        )

    def _write(self, obj) -> None:
        self._held.append(obj)
        self.n_frames += 1
        if len(self._held) >= HELD_FRAMES:
            self._write_held()

    def _write_held(self) -> None:
        held, self._held = self._held, []
        try:
            self._file.write(b"".join(map(self._pack, held)))
        except OSError as exc:
            raise self._failed(exc) from exc

    def _failed(self, exc: OSError) -> RecordError:
        return RecordError(f"the run's record could not be written to {self.path}: {exc}")

    def message(self, direction: str, key: str, payload: bytes, t_wall_ns: int | None = None):
        """Record a message sent or received, with the loop's verdict on it.

        A ``drop`` is stored capped (head, length, digest) while the run's drop budget
        lasts, and only counted past it.

        Parameters
        ----------
        direction : str
            One of :data:`DIRECTIONS` but ``ev``.
        key : str
            The key expression it was sent or received on.
        payload : bytes
            The message as it went on the bus.
        t_wall_ns : int, optional
            When it was sent or received (``time.time_ns``); now when not given.
        """
        if direction == "drop":
            self._drop(key, payload, t_wall_ns)
            return
        self._write([time.time_ns() if t_wall_ns is None else t_wall_ns, direction, key, payload])

    def _drop(self, key: str, payload: bytes, t_wall_ns: int | None) -> None:
        head = payload[:DROP_HEAD_BYTES]
        cost = len(head) + DROP_DIGEST_BYTES + len(key) + _DROP_FRAME_OVERHEAD_BYTES
        if self.drop_bytes_stored + cost > self.drop_budget_bytes:
            self.drops_not_stored += 1
            self.drop_bytes_not_stored += len(payload)
            return
        self.drop_bytes_stored += cost
        digest = hashlib.blake2b(payload, digest_size=DROP_DIGEST_BYTES).digest()
        capped = {"head": bytes(head), "n_bytes": len(payload), "blake2b": digest}
        self._write([time.time_ns() if t_wall_ns is None else t_wall_ns, "drop", key, capped])

    def event(self, name: str, **details) -> None:
        """Record something the hub noticed or did (a death, a policy, a command)."""
        self._write([time.time_ns(), "ev", name, details])

    def tick(self) -> None:
        """Write the frames held; flush if the last flush is ``flush_s`` old. Call often
        (at least every ``flush_s``)."""
        if self._held:
            self._write_held()
        now = time.monotonic()
        if now - self._last_flush >= self.flush_s:
            try:
                self._file.flush()
            except OSError as exc:
                raise self._failed(exc) from exc
            self._last_flush = now

    def abandon(self) -> None:
        """Close the file without writing what is held (after a :class:`RecordError`)."""
        self._held = []
        try:
            self._file.close()
        except OSError:
            pass  # it cannot write what its buffer holds: the error said so already

    def close(self) -> None:
        """Write what is held, flush and sync, and close (closed even when that fails:
        :class:`RecordError` then names the file)."""
        if not self._file.closed:
            try:
                if self.drops_not_stored:
                    self.event(
                        "drops_not_stored",
                        n=self.drops_not_stored,
                        n_bytes=self.drop_bytes_not_stored,
                        budget_bytes=self.drop_budget_bytes,
                    )
                self._write_held()
                self._file.flush()
                os.fsync(self._file.fileno())
            except RecordError:
                raise
            except OSError as exc:
                raise self._failed(exc) from exc
            finally:
                try:
                    self._file.close()
                except OSError:
                    pass  # what it could not write is said above


# --------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class Dropped:
    """A dropped payload as the record keeps it: its first bytes, length and digest."""

    head: bytes
    n_bytes: int
    blake2b: bytes  # hashlib.blake2b(payload, digest_size=16).digest()

    def matches(self, payload: bytes) -> bool:
        """Whether ``payload`` is the one dropped (same length and digest)."""
        digest = hashlib.blake2b(payload, digest_size=len(self.blake2b)).digest()
        return len(payload) == self.n_bytes and digest == self.blake2b


@dataclass
class Frame:
    """One frame of a record: a message or an event, when (wall clock, ns) and how the
    loop took it (``direction``, one of :data:`DIRECTIONS`)."""

    t_wall_ns: int
    direction: str  # one of DIRECTIONS
    key: str
    payload: Any  # bytes for messages, Dropped for drops (v2), dict for events


def _dropped(payload) -> Dropped | None:
    if not isinstance(payload, dict):
        return None
    head, n_bytes, digest = payload.get("head"), payload.get("n_bytes"), payload.get("blake2b")
    if isinstance(head, bytes) and isinstance(n_bytes, int) and isinstance(digest, bytes):
        return Dropped(head, n_bytes, digest)
    return None


def _is_frame(item) -> bool:
    return (
        isinstance(item, list)
        and len(item) == 4
        and isinstance(item[0], int)
        and item[1] in DIRECTIONS
        and isinstance(item[2], str)
    )


# A frame starts as a msgpack array of four whose first item, a time in ns, is a uint64.
_FRAME_START = b"\x94\xcf"


def _unpacker(fh) -> msgpack.Unpacker:
    return msgpack.Unpacker(
        fh, raw=False, strict_map_key=False, max_buffer_size=MAX_MESSAGE_BYTES + (1 << 20)
    )


def _resync(fh, size: int, after: int) -> int | None:
    """The first place past ``after`` where whole frames start again (two in a row, or one
    that ends the file); None if there is none (a tail cut short)."""
    at = after
    while True:
        found, chunk_at = -1, at + 1
        while found < 0 and chunk_at < size:  # search in chunks (a record may be GBs)
            fh.seek(chunk_at)
            chunk = fh.read(1 << 20)
            if not chunk:
                return None
            hit = chunk.find(_FRAME_START)
            found = chunk_at + hit if hit >= 0 else -1
            chunk_at += max(len(chunk) - 1, 1)
        if found < 0:
            return None
        fh.seek(found)
        candidate, items = _unpacker(fh), []
        try:
            for _ in range(2):
                item = next(candidate)
                if not _is_frame(item):
                    break
                items.append(item)
        except StopIteration:
            pass  # the file ends after it
        except (ValueError, msgpack.UnpackException):
            items = []
        ends_file = len(items) == 1 and found + candidate.tell() == size
        if len(items) == 2 or ends_file:
            return found
        at = found


def iter_frames(path: str | Path, skipped: list | None = None) -> Iterator[Frame]:
    """Frames of a record file, in order.

    A tail cut short (a run still going, a hub killed mid-write) ends the frames quietly.
    A damaged stretch with whole frames after it (a flipped byte in a frame's header) is
    skipped: reading goes on at the next place where whole frames start again.

    Parameters
    ----------
    path : str or Path
        The record file.
    skipped : list, optional
        Given, each stretch skipped is appended to it as ``(offset, n_bytes)``.

    Raises
    ------
    RunReadError
        Not a NeuVision record, or a format version not readable.
    """
    size = os.path.getsize(path)
    with open(path, "rb") as fh:
        unpacker = _unpacker(fh)
        try:
            header = next(unpacker)
        except (StopIteration, ValueError, msgpack.UnpackException):
            return
        if not isinstance(header, dict) or header.get("format") != FORMAT:
            raise RunReadError(f"{path} is not a NeuVision record")
        if header.get("v") not in READABLE_VERSIONS:
            raise RunReadError(f"{path}: record format version {header.get('v')!r} not readable")
        base, good = 0, unpacker.tell()  # the unpacker's start in the file; the last frame's end
        while True:
            try:
                item = next(unpacker)
                whole = _is_frame(item)
            except StopIteration:
                whole = False  # the end, or a length that runs past it
            except (ValueError, msgpack.UnpackException):
                whole = False
            if whole:
                good = base + unpacker.tell()
                if item[1] == "drop":
                    item[3] = _dropped(item[3]) or item[3]
                yield Frame(*item)
                continue
            if good >= size:
                return
            at = _resync(fh, size, good)
            if at is None:
                return  # a tail cut short
            if skipped is not None:
                skipped.append((good, at - good))
            fh.seek(at)
            base, unpacker = at, _unpacker(fh)


@dataclass
class RunRecord:
    """A run read back: manifest and frames, with typed views of the loop messages."""

    run_dir: Path
    manifest: dict[str, Any]
    frames: list[Frame] = field(repr=False)
    #: stretches of the record file that could not be read and were skipped: (offset, bytes)
    skipped: list[tuple[int, int]] = field(default_factory=list)
    # each loop message kind decoded once: (direction, message) of the frames that decode,
    # and how many of its frames did not
    _decoded: dict[type, tuple[list, int]] = field(default_factory=dict, repr=False)

    @property
    def events(self) -> list[Frame]:
        """The hub's events (``ev`` frames: the name in ``key``, details in ``payload``)."""
        return [f for f in self.frames if f.direction == "ev"]

    def steps_recorded(self) -> int:
        """The steps the record holds: the most messages of one key, sent or received (the
        hub sends each endpoint an input a step, and takes a reply a step). A whole record
        holds at least the manifest's ``steps``; one cut short (its hub killed before it
        wrote, a damaged file) holds fewer."""
        counts: dict[str, int] = {}
        for f in self.frames:
            if f.direction in _STEP_DIRECTIONS:
                counts[f.key] = counts.get(f.key, 0) + 1
        held = max(counts.values(), default=0)
        steps = self.manifest.get("steps")
        return min(held, steps) if isinstance(steps, int) else held  # not the robot's stop

    def short_note(self) -> str:
        """Why what the record holds is less than the run (empty: it is all there)."""
        steps = self.manifest.get("steps")
        held = self.steps_recorded()
        if not isinstance(steps, int) or held >= steps:
            return ""
        if not self.frames and not (self.run_dir / RECORD_FILE).exists():
            return (
                f"the run folder holds no {RECORD_FILE} (removed, or the run was made with "
                f"record.enabled = false): none of the run's {steps} steps is recorded"
            )
        return (
            f"the record holds {held} of the run's {steps} steps: it was cut short or is "
            "damaged past that point, and what is read from it covers those steps only"
        )

    def network_bursts(self) -> list[dict]:
        """The network bursts the burst observer reported during the run (its
        ``network_burst`` events' details), sorted by core start; in a record from before
        cores were recorded, the extent stands for the core."""
        rows = []
        for e in self.events:
            if e.key == "network_burst":
                row = dict(e.payload)
                row.setdefault("core_start_ms", row["start_ms"])
                row.setdefault("core_end_ms", row["end_ms"])
                rows.append(row)
        return sorted(rows, key=lambda row: row["core_start_ms"])

    @property
    def drops(self) -> list[Frame]:
        """Dropped payloads (a :class:`Dropped` each; whole bytes in a version 1 record)."""
        return [f for f in self.frames if f.direction == "drop"]

    def decoded(self, kind: type, *directions: str) -> list:
        """Valid messages of one type, in the record's order.

        A recorded message that does not decode is left out (it can only be damage: the hub
        records what it sent, and what it took once checked); :meth:`damage_note` says
        how many were.

        Parameters
        ----------
        kind : type
            ``MotorCommand``, ``SensorReading``, ``Stimulation``, ``SpikeBatch`` or
            ``Description`` (told apart by their key).
        *directions : str
            The directions to keep (:data:`DIRECTIONS`); all when none is given.
        """
        messages, _ = self._decode(kind)
        return [m for d, m in messages if not directions or d in directions]

    def _decode(self, kind: type) -> tuple[list, int]:
        if kind not in self._decoded:
            suffix, messages, damaged = _SUFFIX[kind], [], 0
            for f in self.frames:
                if not isinstance(f.payload, bytes) or not f.key.endswith(suffix):
                    continue  # events, and drops stored capped
                if f.direction == "drop":
                    continue  # refused when it came (version 1 records keep it whole)
                try:
                    messages.append((f.direction, kind.decode(f.payload)))
                except ProtocolError:
                    damaged += 1
            self._decoded[kind] = (messages, damaged)
        return self._decoded[kind]

    def damaged(self) -> dict[str, int]:
        """Recorded loop messages that no longer decode, by kind (none: empty)."""
        counts = {kind.__name__: self._decode(kind)[1] for kind in _SUFFIX}
        return {name: n for name, n in counts.items() if n}

    def damage_note(self) -> str:
        """What of the record is damaged and left out of what is read (empty: nothing)."""
        notes = []
        if damaged := self.damaged():
            kinds = ", ".join(f"{n} {name}" for name, n in damaged.items())
            n = sum(damaged.values())
            what = "1 recorded message is" if n == 1 else f"{n} recorded messages are"
            notes.append(f"{what} damaged ({kinds}): no longer decoding, left out of what is read")
        if self.skipped:
            n_bytes = sum(n for _, n in self.skipped)
            where = ", ".join(f"{n} at byte {at}" for at, n in self.skipped[:3])
            more = f" and {len(self.skipped) - 3} more" if len(self.skipped) > 3 else ""
            notes.append(
                f"{n_bytes} bytes of the record file could not be read ({where}{more}) and "
                "were skipped: the frames in them are lost, those after them are read"
            )
        return "; ".join(notes)

    def descriptions(self) -> dict[str, Description]:
        """The endpoints' descriptions the hub received, by role (the last of each role)."""
        return {d.role: d for d in self.decoded(Description, "rx")}

    def spikes(self) -> tuple[np.ndarray, np.ndarray]:
        """All received spikes as ``(channel uint32, t_ms float64 absolute)``, in time order
        (a device's late spikes at their true times included).

        The record holds replies in the order they arrived, which need not be the steps'
        (a late batch, two endpoints' threads): the order is made here, for every reader.
        """
        batches = self.decoded(SpikeBatch, *DATA_DIRECTIONS)
        if not batches:
            return np.zeros(0, np.uint32), np.zeros(0, np.float64)
        late = [b for b in batches if b.late_channel is not None]
        channel = np.concatenate([b.channel for b in batches] + [b.late_channel for b in late])
        t_ms = np.concatenate(
            [b.t0_s * 1e3 + b.t_ms.astype(np.float64) for b in batches]
            + [b.t0_s * 1e3 + b.late_t_ms.astype(np.float64) for b in late]
        )
        order = np.argsort(t_ms, kind="stable")
        return channel[order], t_ms[order]

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Received body poses as ``(t_s[n], pose[n, 3])``, in step order."""
        readings = sorted(self.decoded(SensorReading, *DATA_DIRECTIONS), key=lambda r: r.step)
        t_s = np.array([r.t_s for r in readings], dtype=np.float64)
        poses = np.array([r.pose for r in readings], dtype=np.float64).reshape(-1, 3)
        return t_s, poses


_SUFFIX = {
    MotorCommand: "/motor",
    SensorReading: "/sensors",
    Stimulation: "/stim",
    SpikeBatch: "/spikes",
    Description: "/describe",
}


class RunReadError(ValueError):
    """A run folder's manifest or record cannot be read: damaged, or not a NeuVision
    run's. The message names the file and what is wrong with it."""


def read_manifest(run_dir: str | Path) -> dict[str, Any]:
    """A run folder's manifest; a missing one (killed before start) reads as ``{}``.

    A manifest that says "running" while its hub is gone (:func:`hub_gone`) reads as
    outcome ``"unfinished"``, with the reason (the file is left as it is): the record
    holds what the hub had written when it ended.

    Raises
    ------
    RunReadError
        The manifest is not JSON, or not a JSON object.
    """
    manifest_path = Path(run_dir) / MANIFEST_FILE
    manifest: Any = {}
    if manifest_path.exists():
        try:
            manifest = json.loads(manifest_path.read_text())
        except (ValueError, UnicodeDecodeError) as exc:
            raise RunReadError(f"{manifest_path} is damaged (not JSON: {exc})") from None
    if not isinstance(manifest, dict):
        raise RunReadError(
            f"{manifest_path} is not a run's manifest (a JSON {type(manifest).__name__}, "
            "not an object)"
        )
    if hub_gone(manifest):
        manifest["outcome"] = UNFINISHED
        manifest.setdefault(
            "reason",
            "its hub ended without closing the run (killed outright, crashed, or its host "
            "stopped): the record holds what the hub had written by then",
        )
    return manifest


def read_run(run_dir: str | Path) -> RunRecord:
    """Read a run folder: its manifest (:func:`read_manifest`) and its record's frames."""
    run_dir = Path(run_dir)
    manifest = read_manifest(run_dir)
    record_path = run_dir / RECORD_FILE
    skipped: list[tuple[int, int]] = []
    frames = list(iter_frames(record_path, skipped)) if record_path.exists() else []
    return RunRecord(run_dir, manifest, frames, skipped)
