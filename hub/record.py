"""The run record: an append-only file of every message, and the run manifest.

A run folder holds ``manifest.json`` (config, seed, versions, hosts, start,
end, outcome, timing) and ``record.nvrec``: a stream of msgpack frames, the
first a header map, then one list per message or event::

    [t_wall_ns, direction, key, payload_bytes]   # a message the hub sent or received
    [t_wall_ns, "ev", name, {details}]           # something the hub noticed or did

where direction is ``tx`` (sent), ``rx`` (received and used by the loop),
``late`` (valid, but arrived after its deadline: real data the loop did not
use) or ``drop`` (received and dropped: malformed, stale, duplicate, future).

The writer flushes at least every ``flush_s`` (≤ 1 s), so a run killed at any
moment leaves a record readable up to its last flush; the reader returns
everything up to a truncated or damaged tail without error.
"""

from __future__ import annotations

import datetime as _dt
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

from hub.protocol import (
    Description,
    MotorCommand,
    ProtocolError,
    SensorReading,
    SpikeBatch,
    Stimulation,
)

RECORD_FILE = "record.nvrec"
MANIFEST_FILE = "manifest.json"
FORMAT = "neuvision-record"
FORMAT_VERSION = 1
DIRECTIONS = ("tx", "rx", "late", "drop", "ev")
# What the analysis reads as the culture's and body's real output.
DATA_DIRECTIONS = ("rx", "late")
WRITE_BUFFER_BYTES = 1 << 20
HELD_FRAMES = 1024  # frames held at most before they are written


def utc_now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds")


def new_run_dir(runs_dir: str | Path, name: str) -> Path:
    """Create ``runs_dir/<UTC time>-<name>[-n]`` and return it."""
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


def host() -> dict[str, str]:
    return {"hostname": socket.gethostname(), "platform": platform.platform()}


def write_manifest(run_dir: Path, manifest: dict[str, Any]) -> None:
    """Write ``manifest.json`` atomically (a reader never sees half a file)."""
    tmp = run_dir / (MANIFEST_FILE + ".tmp")
    tmp.write_text(json.dumps(manifest, indent=2, default=_json_default))
    os.replace(tmp, run_dir / MANIFEST_FILE)


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


class Recorder:
    """Appends frames to ``record.nvrec``, flushing at least every ``flush_s``.

    Frames are held, and packed and written by :meth:`tick` (or once HELD_FRAMES are
    held), so that recording a message costs the loop's critical path one append."""

    def __init__(self, run_dir: str | Path, *, flush_s: float = 0.5):
        self.path = Path(run_dir) / RECORD_FILE
        self.flush_s = flush_s
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
        self._file.write(b"".join(map(self._pack, held)))

    def message(self, direction: str, key: str, payload: bytes, t_wall_ns: int | None = None):
        """Record a message sent or received, with the loop's verdict on it."""
        self._write([t_wall_ns or time.time_ns(), direction, key, payload])

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
            self._file.flush()
            self._last_flush = now

    def close(self) -> None:
        if not self._file.closed:
            self._write_held()
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()


# --------------------------------------------------------------------------- reading


@dataclass
class Frame:
    t_wall_ns: int
    direction: str  # one of DIRECTIONS
    key: str
    payload: Any  # bytes for messages, dict for events


def iter_frames(path: str | Path) -> Iterator[Frame]:
    """Frames of a record file, in order, stopping quietly at a truncated or damaged tail."""
    with open(path, "rb") as fh:
        unpacker = msgpack.Unpacker(fh, raw=False, strict_map_key=False)
        try:
            header = next(unpacker)
        except (StopIteration, ValueError, msgpack.UnpackException):
            return
        if not isinstance(header, dict) or header.get("format") != FORMAT:
            raise ValueError(f"{path} is not a NeuVision record")
        while True:
            try:
                item = next(unpacker)
            except StopIteration:
                return
            except (ValueError, msgpack.UnpackException):
                return  # damaged tail
            if not (
                isinstance(item, list)
                and len(item) == 4
                and isinstance(item[0], int)
                and item[1] in DIRECTIONS
                and isinstance(item[2], str)
            ):
                return
            yield Frame(*item)


@dataclass
class RunRecord:
    """A run read back: manifest and frames, with typed views of the loop messages."""

    run_dir: Path
    manifest: dict[str, Any]
    frames: list[Frame] = field(repr=False)

    @property
    def events(self) -> list[Frame]:
        return [f for f in self.frames if f.direction == "ev"]

    def decoded(self, kind: type, *directions: str) -> list:
        """Valid messages of type ``kind`` with one of ``directions`` (default: all), in order."""
        suffix = _SUFFIX[kind]
        out = []
        for f in self.frames:
            if f.direction == "ev" or not f.key.endswith(suffix):
                continue
            if directions and f.direction not in directions:
                continue
            try:
                out.append(kind.decode(f.payload))
            except ProtocolError:
                continue
        return out

    def descriptions(self) -> dict[str, Description]:
        return {d.role: d for d in self.decoded(Description, "rx")}

    def spikes(self) -> tuple[np.ndarray, np.ndarray]:
        """All received spikes as ``(channel uint32, t_ms float64 absolute)``."""
        batches = self.decoded(SpikeBatch, *DATA_DIRECTIONS)
        if not batches:
            return np.zeros(0, np.uint32), np.zeros(0, np.float64)
        channel = np.concatenate([b.channel for b in batches])
        t_ms = np.concatenate([b.t0_s * 1e3 + b.t_ms.astype(np.float64) for b in batches])
        return channel, t_ms

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Received body poses as ``(t_s[n], pose[n, 3])``."""
        readings = self.decoded(SensorReading, *DATA_DIRECTIONS)
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


def read_run(run_dir: str | Path) -> RunRecord:
    """Read a run folder; a missing manifest (killed before start) reads as ``{}``."""
    run_dir = Path(run_dir)
    manifest_path = run_dir / MANIFEST_FILE
    manifest = json.loads(manifest_path.read_text()) if manifest_path.exists() else {}
    record_path = run_dir / RECORD_FILE
    frames = list(iter_frames(record_path)) if record_path.exists() else []
    return RunRecord(run_dir, manifest, frames)
