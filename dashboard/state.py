"""What the page shows, kept between frames: the newest of everything and short histories.

A source (:mod:`dashboard.observer` live, :mod:`dashboard.replay` from a record) feeds a
:class:`FrameState` plain values — a pose, a batch of spikes as arrays, the hub's status
as a dict — and the server asks it for a frame per page (:meth:`FrameState.frame`): a
JSON-ready dict with the newest values and, for the streams (the trail, spikes, pulses,
rates, the Center of Activity, network bursts), what that page has not had yet. A page
that missed frames gets everything since its last one in the next: frames are dropped,
never data (within the histories kept below).

Everything is stamped with *run time* (ms or s from the run's start, as the messages'
windows say), so a replay computes the same rates and Center of Activity as the live run.
Spikes come with the stretch of run time they cover; a 50 ms bin of the rates is shown
only when at least half of it was covered (a source that skips windows, as the live one
does in a lockstep run faster than the page, leaves gaps rather than false zeros).

No bus, no web: plain numpy, unit-tested on its own. Not thread-safe by itself: callers
hold :attr:`FrameState.lock`.
"""

from __future__ import annotations

import base64
import math
import threading
from collections import deque
from dataclasses import dataclass, field

import numpy as np

RASTER_S = 4.0  # spikes and pulses kept for the scrolling raster
BIN_MS = 50.0  # rates and the Center of Activity per bin of run time (the CA decoder's window)
RATE_HISTORY_S = 20.0  # rate bins kept
CA_PATH_S = 3.0  # the Center of Activity's recent path
BURSTS_KEPT_S = 60.0  # network bursts kept (by their end)
ACTIVITY_TAU_MS = 150.0  # decay of a channel's colour on the culture map
LIT_MS = 100.0  # a stimulated site stays lit this long
TRAIL_POINTS = 5000  # trail points kept
TRAIL_STEP_M = 0.002  # a trail point is added when the robot moved this far
MAX_SPIKES_PER_FRAME = 20_000  # beyond: the newest only (counted in raster_capped)
# ... but a page's first frame (a new page, a new run, a jump in a replay) gets the whole
# raster up to this many (a 4 s raster of 1,024 channels at 60 spikes/s each)
MAX_SPIKES_ON_RESET = 250_000
BURSTS_SEEN_MAX = 256  # network bursts remembered as given (the hub repeats the latest)
# A bin's sums after its covered ms and its spike count: each channel's share of them
PER_CHANNEL = ("exc", "inh", "x_um", "y_um")
# Bins x channels up to which a view's spikes are summed through a count matrix (one
# bincount and a product: ~2.5x cheaper than a weighted count per sum); past it (many bins
# of a large culture at once) one weighted count per sum, with no matrix that large
COUNT_MATRIX_MAX = 1 << 18


class Tape:
    """Items stamped with run time, each with a sequence number; a reader asks for what
    came after its cursor.

    Parameters
    ----------
    keep_s : float
        Items older than this (s of run time) behind the time `trim` is given are let go
        (``math.inf``: none).
    max_items : int or None
        At most this many kept, the oldest let go first (None: no limit).
    """

    def __init__(self, keep_s: float, max_items: int | None = None):
        self.keep_s = keep_s
        self._items: deque = deque(maxlen=max_items)  # (seq, t_s, item)
        self.seq = 0  # the last item's number

    def add(self, t_s: float, item) -> None:
        """Append ``item``, stamped with run time ``t_s`` (s), as the next number.

        Parameters
        ----------
        t_s : float
            Run time (s); items are expected in time order.
        item : object
            Anything; `since` hands it back as it is.
        """
        self.seq += 1
        self._items.append((self.seq, t_s, item))

    def trim(self, now_s: float) -> None:
        """Let go of the items stamped more than ``keep_s`` before ``now_s`` (s)."""
        items, oldest = self._items, now_s - self.keep_s
        while items and items[0][1] < oldest:
            items.popleft()

    def since(self, cursor: int) -> list:
        """Items numbered after ``cursor`` that are still kept, oldest first."""
        items = self._items
        if not items or cursor >= self.seq:
            return []
        start = max(cursor + 1 - items[0][0], 0)
        return [items[i][2] for i in range(start, len(items))]

    def newest_first(self):
        """The items kept, newest first (no copy: not while items are added)."""
        return (item for _, _, item in reversed(self._items))

    def __len__(self) -> int:
        return len(self._items)


STREAMS = ("trail", "spikes", "pulses", "rates", "ca", "bursts")


@dataclass
class Reader:
    """One page's place in the state: the generation it saw and a cursor per stream."""

    generation: int = -1
    scene_version: int = -1
    cursors: dict = field(default_factory=dict)


class FrameState:
    """The dashboard's state (see the module's docstring).

    The culture's layout comes with the scene (:meth:`set_scene`): spikes and pulses on
    channels it does not list are ignored, and before a scene none are kept.
    """

    def __init__(self):
        self.lock = threading.RLock()
        self.scene: dict | None = None
        self.scene_version = 0
        self.generation = 0
        self.source: dict = {}  # what the page says about where the data comes from
        self.status: dict = {}  # the hub's latest HubStatus (or the replay's stand-in)
        self.endpoints: dict = {}  # role -> what the endpoint said of itself
        self.replay: dict | None = None
        self.observer: dict = {}  # the observer's own counters (dropped messages...)
        self._layout(None)
        self.reset()

    # ------------------------------------------------------------------ set-up

    def set_scene(self, scene: dict | None) -> None:
        """A new arena, body and culture (plain dict, :func:`dashboard.scene.build_scene`):
        every history starts again."""
        self.scene = scene
        self.scene_version += 1
        self._layout((scene or {}).get("culture"))
        self.reset()

    def _layout(self, culture: dict | None) -> None:
        if not culture or not culture.get("channel"):
            self.n_channels = 0
            self._table = np.zeros(1, np.int64) - 1
            self._per_channel = np.zeros((len(PER_CHANNEL), 0))
            self._n_all, self._n_exc, self._n_inh = 1, 0, 0
            self._index_bytes = 2
            return
        ids = np.asarray(culture["channel"], np.int64)
        self.n_channels = ids.size
        self._table = np.full(int(ids.max()) + 2, -1, np.int64)  # id -> index; last: unknown
        self._table[ids] = np.arange(ids.size)
        cell = culture.get("cell_type")
        cell = np.asarray(cell) if cell is not None else np.full(ids.size, -1)
        exc, inh = cell == 0, cell == 1
        # what each channel adds to a bin's sums (PER_CHANNEL), one row per sum
        self._per_channel = np.stack(
            [exc, inh, np.asarray(culture["x_um"]), np.asarray(culture["y_um"])]
        ).astype(np.float64)
        # the rates' denominators: every channel, the excitatory ones, the inhibitory ones
        self._n_all, self._n_exc, self._n_inh = ids.size, int(exc.sum()), int(inh.sum())
        self._index_bytes = 2 if ids.size <= 1 << 16 else 4

    def reset(self) -> None:
        """Empty every history (a new run, a jump in a replay); the scene stays."""
        self.generation += 1
        self.t_ms = 0.0  # newest run time seen
        self.step = -1
        self.pose: list | None = None
        self.ranges: list | None = None
        self.contact = False
        self.motor: list | None = None
        self._motor_step = -1  # the step of the motor command shown
        self.tapes = {
            "trail": Tape(math.inf, TRAIL_POINTS),
            "spikes": Tape(RASTER_S),
            "pulses": Tape(RASTER_S),
            "rates": Tape(RATE_HISTORY_S),
            "ca": Tape(CA_PATH_S),
            "bursts": Tape(BURSTS_KEPT_S),
        }
        self._last_trail: tuple[float, float] | None = None
        self._activity = np.zeros(self.n_channels)
        self._activity_ms = 0.0
        # open bins: [covered ms, all, exc, inh, sum x, sum y]; those before _closed are out
        self._bins: dict[int, list[float]] = {}
        self._closed = -(1 << 62)
        self._burst_starts: set[float] = set()
        self.raster_capped = 0

    # ------------------------------------------------------------------ feeding

    def add_sensors(
        self, step: int, t_s: float, pose, ranges, contact: bool, trail: bool = True
    ) -> None:
        """A body's reading: the newest pose (by step) and, with ``trail``, a point of the
        trail.

        Parameters
        ----------
        step : int
            The reading's step; an older one than the newest seen adds only to the trail.
        t_s : float
            Its run time (s).
        pose : sequence of float
            ``(x_m, y_m, heading_rad)``.
        ranges : sequence of float
            The range finders' readings (m).
        contact : bool
            Whether the body touches an obstacle or the wall.
        trail : bool
            Whether the pose is also a point of the trail (False when the trail comes
            apart, as in a hub's view).
        """
        if trail:
            self.add_trail([pose[:2]], t_s)
        if step >= self.step:
            self.step = int(step)
            self.pose = [float(v) for v in pose]
            self.ranges = [round(float(r), 5) for r in ranges]
            self.contact = bool(contact)
        self._advance(t_s * 1e3)

    def add_trail(self, points, t_s: float | None = None) -> None:
        """Positions of the body in step order (one point kept every TRAIL_STEP_M of travel).

        Parameters
        ----------
        points : array_like, float[k, 2]
            ``[[x_m, y_m], ...]``.
        t_s : float, optional
            Their run time (s); default the newest seen.
        """
        t_s = self.t_ms / 1e3 if t_s is None else t_s
        tape, last = self.tapes["trail"], self._last_trail
        for x, y in np.asarray(points, np.float64).tolist():
            if last is None or math.hypot(x - last[0], y - last[1]) >= TRAIL_STEP_M:
                last = (x, y)
                tape.add(t_s, [round(x, 5), round(y, 5)])
        self._last_trail = last

    def add_motor(self, step: int, left_mps: float, right_mps: float) -> None:
        """A motor command: the newest by step is shown.

        Parameters
        ----------
        step : int
            The command's step; one older than the newest seen is not shown.
        left_mps, right_mps : float
            Wheel speeds (m/s).
        """
        if step >= self._motor_step:
            self._motor_step = int(step)
            self.motor = [float(left_mps), float(right_mps)]

    def add_spikes(self, channel, t_ms, from_ms: float, until_ms: float) -> None:
        """Every spike of the run time ``[from_ms, until_ms)``: the raster, the culture
        map's activity, and the rates and Center of Activity of the bins it covers.

        Parameters
        ----------
        channel : array_like of int
            Channel ids; those the scene's culture does not list are ignored.
        t_ms : array_like of float
            Run times (ms), in time order.
        from_ms, until_ms : float
            The stretch of run time the spikes cover (ms); none when empty.
        """
        if not self.n_channels or not until_ms > from_ms:
            return
        idx = self._index(channel)
        t_ms = np.asarray(t_ms, np.float64)
        known = idx >= 0
        if not known.all():
            idx, t_ms = idx[known], t_ms[known]
        now_ms = max(until_ms, self._activity_ms)
        self._decay_to(now_ms)
        if idx.size:  # each spike as decayed from its own time to now
            weight = t_ms - now_ms
            np.minimum(weight, 0.0, out=weight)
            np.divide(weight, ACTIVITY_TAU_MS, out=weight)
            self._activity += np.bincount(
                idx, np.exp(weight, out=weight), minlength=self.n_channels
            )
            self.tapes["spikes"].add(float(t_ms[-1]) / 1e3, (t_ms, idx))
        self._bin(idx, t_ms, from_ms, until_ms)
        self._close_bins(until_ms)
        self._advance(until_ms)

    def add_pulses(self, channel, t_ms) -> None:
        """Stimulation pulses, for the raster and the culture map.

        Parameters
        ----------
        channel : array_like of int
            Channel ids; those the scene's culture does not list are ignored.
        t_ms : array_like of float
            Run times of delivery (ms).
        """
        if not self.n_channels:
            return
        idx = self._index(channel)
        t_ms = np.asarray(t_ms, np.float64)
        known = idx >= 0
        if known.any():
            self.tapes["pulses"].add(float(t_ms[known].max()) / 1e3, (t_ms[known], idx[known]))

    def add_bursts(self, bursts) -> None:
        """Network bursts ``[start_ms, end_ms, n_channels, core_start_ms, core_end_ms]``: the
        extent and the core (docs/analysis.md; a record from before the core was noted gives
        only the extent, which then stands for it), each once however often given."""
        for start_ms, end_ms, n, *core in bursts:
            core_start_ms, core_end_ms = core or (start_ms, end_ms)
            if core_start_ms in self._burst_starts:  # cores, unlike extents, never overlap
                continue
            self._burst_starts.add(core_start_ms)
            self.tapes["bursts"].add(
                end_ms / 1e3, [start_ms, end_ms, n, core_start_ms, core_end_ms]
            )
        if len(self._burst_starts) > BURSTS_SEEN_MAX:  # forget those no longer kept
            self._burst_starts = {b[3] for b in self.tapes["bursts"].since(0)}

    def set_status(self, status: dict) -> None:
        """The hub's newest status (``HubStatus.to_dict()``, or a replay's stand-in)."""
        self.status = status

    def set_endpoints(self, endpoints: dict) -> None:
        """What each endpoint said of itself, by role (``id``, ``alive``, ``kind``,
        ``counters``)."""
        self.endpoints = endpoints

    # ------------------------------------------------------------------ internals

    def _index(self, channel) -> np.ndarray:
        # clipped into the table, whose last entry is "unknown" (np.take: one pass)
        return np.take(self._table, np.asarray(channel, np.int64), mode="clip")

    def _advance(self, t_ms: float) -> None:
        if t_ms > self.t_ms:
            self.t_ms = t_ms
            now_s = t_ms / 1e3
            for tape in self.tapes.values():
                tape.trim(now_s)

    def _decay_to(self, t_ms: float) -> None:
        dt = t_ms - self._activity_ms
        if dt > 0:
            self._activity *= math.exp(-dt / ACTIVITY_TAU_MS)
            self._activity_ms = t_ms

    def _bin(self, idx: np.ndarray, t_ms: np.ndarray, from_ms: float, until_ms: float) -> None:
        """Add the covered time and the spikes of ``[from_ms, until_ms)`` to their bins."""
        b0 = int(math.floor(from_ms / BIN_MS))
        b1 = int(math.floor(until_ms / BIN_MS - 1e-9))  # the bin holding until_ms's instant
        n = b1 - b0 + 1
        edges = np.arange(b0, b1 + 2) * BIN_MS
        covered = np.minimum(edges[1:], until_ms) - np.maximum(edges[:-1], from_ms)
        if idx.size:
            rel = np.floor(t_ms / BIN_MS).astype(np.int64)
            rel -= b0
            np.clip(rel, 0, n - 1, out=rel)
            c = self.n_channels
            if n * c <= COUNT_MATRIX_MAX:  # each bin's spikes per channel, then one product
                counts = np.bincount(rel * c + idx, minlength=n * c).reshape(n, c)
                per_bin = [counts.sum(axis=1), counts @ self._per_channel.T]
            else:  # one weighted count per sum (np.take: far cheaper than fancy indexing)
                shares = np.take(self._per_channel, idx, axis=1)
                per_bin = [np.bincount(rel, minlength=n)]
                per_bin += [np.bincount(rel, row, minlength=n) for row in shares]
            rows = np.column_stack([covered, *per_bin]).tolist()
        else:
            rows = [[c, 0.0, 0.0, 0.0, 0.0, 0.0] for c in covered.tolist()]
        bins, closed = self._bins, self._closed
        for b, row in enumerate(rows, start=b0):
            if b < closed:
                continue  # a late reply for a bin already shown: left out
            acc = bins.get(b)
            if acc is None:
                bins[b] = row
            else:
                for k, value in enumerate(row):
                    acc[k] += value

    def _close_bins(self, until_ms: float) -> None:
        """Emit every bin that ends at or before ``until_ms`` and was covered at least half:
        a point of the rates and one of the Center of Activity's path."""
        last = int(math.floor(until_ms / BIN_MS + 1e-9))  # bins before this one are whole
        self._closed = max(self._closed, last)
        n_all, n_exc, n_inh = self._n_all, self._n_exc, self._n_inh
        for b in sorted(b for b in self._bins if b < last):
            covered, n, exc, inh, sx, sy = self._bins.pop(b)
            if covered < BIN_MS / 2:
                continue
            t_s = round((b + 1) * BIN_MS / 1e3, 4)
            to_hz = 1e3 / covered
            rates = [t_s, round(n / n_all * to_hz, 3)]
            rates.append(round(exc / n_exc * to_hz, 3) if n_exc else None)
            rates.append(round(inh / n_inh * to_hz, 3) if n_inh else None)
            self.tapes["rates"].add(t_s, rates)
            if n > 0:
                self.tapes["ca"].add(t_s, [t_s, round(sx / n, 2), round(sy / n, 2)])

    # ------------------------------------------------------------------ frames

    def frame(self, reader: Reader) -> dict:
        """The frame for one page: the newest values, and each stream since ``reader``'s
        cursors (all that is kept, with ``reset``, when the page has another generation)."""
        reset = reader.generation != self.generation
        if reset:
            reader.generation = self.generation
            reader.cursors = dict.fromkeys(STREAMS, 0)
        streams = {}
        for name in STREAMS:
            tape = self.tapes[name]
            streams[name] = tape.since(reader.cursors.get(name, 0))
            reader.cursors[name] = tape.seq
        self._decay_to(self.t_ms)
        now_ms = self.t_ms
        out = {
            "type": "frame",
            "generation": self.generation,
            "reset": reset,
            "t_s": round(now_ms / 1e3, 4),
            "step": self.step,
            "pose": self.pose,
            "ranges": self.ranges,
            "contact": self.contact,
            "motor": self.motor,
            "trail": streams["trail"],
            "spikes": self._events(
                streams["spikes"], cap=MAX_SPIKES_ON_RESET if reset else MAX_SPIKES_PER_FRAME
            ),
            "pulses": self._events(streams["pulses"]),
            "rates": streams["rates"],
            "ca": streams["ca"],
            "bursts": streams["bursts"],
            "activity": self._activity_bytes(),
            "lit": self._lit(now_ms),
            "status": self.status,
            "endpoints": self.endpoints,
            "source": self.source,
            "observer": self.observer,
        }
        if self.replay is not None:
            out["replay"] = self.replay
        return out

    def _events(self, parts: list, cap: int | None = None) -> dict:
        """A stream's (times ms, channel indices) as base64 of little-endian arrays: ``n``,
        ``t0`` (ms), ``t`` (float32 ms after ``t0``) and ``i`` (channel indices in the
        scene's order, unsigned integers of ``i_bytes`` bytes: 2 for up to 65,536 channels,
        else 4) — six bytes a spike, and no per-spike Python. Past ``cap``
        only the newest go, and ``capped_before_ms`` says from when: the page shows the
        time before as not shown, never as silence."""
        if not parts:
            return {"n": 0, "t0": 0.0, "t": "", "i": "", "i_bytes": self._index_bytes}
        t_ms = np.concatenate([p[0] for p in parts])
        idx = np.concatenate([p[1] for p in parts])
        capped_before_ms = None
        if cap is not None and t_ms.size > cap:
            self.raster_capped += t_ms.size - cap
            t_ms, idx = t_ms[-cap:], idx[-cap:]
            capped_before_ms = float(t_ms.min())
        t0 = float(np.floor(t_ms.min()))
        out = {
            "n": int(t_ms.size),
            "t0": t0,
            "t": _b64((t_ms - t0).astype("<f4")),
            "i": _b64(idx.astype(f"<u{self._index_bytes}")),
            "i_bytes": self._index_bytes,
        }
        if capped_before_ms is not None:
            out["capped_before_ms"] = capped_before_ms
        return out

    def _activity_bytes(self) -> str:
        """Each channel's recent activity, 0-255 (1 - exp(-a), a the decayed spike count),
        base64."""
        if not self.n_channels:
            return ""
        level = -np.expm1(-self._activity) * 255.0
        return _b64(level.astype(np.uint8))

    def _lit(self, now_ms: float) -> list:
        """Channel indices stimulated within the last LIT_MS."""
        lit = set()
        for t_ms, idx in self.tapes["pulses"].newest_first():
            recent = t_ms >= now_ms - LIT_MS
            if not recent.any():
                break
            lit.update(idx[recent].tolist())
        return sorted(lit)


def _b64(array: np.ndarray) -> str:
    return base64.b64encode(array.tobytes()).decode("ascii")
