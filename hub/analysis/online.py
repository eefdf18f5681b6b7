"""Online ("on the fly") burst and network-burst detection on a live spike stream.

``OnlineBurstDetector.feed(channel, t_ms, until_ms)`` takes one window of spikes at a time and
returns the bursts and network bursts that became *complete* with it. Over a whole stream
(ending with ``flush()``) it reports exactly the bursts of ``bursts.detect_bursts`` and the
network bursts of ``network_bursts.detect_network_bursts`` on the same spikes.

When is an event complete? With a watermark ``W`` (every spike before ``W`` has been fed):

- a spike's core status is final once ``W - t > window_ms`` (no later spike can join its run);
- a burst is complete once its following spike is final and cannot join it, or once
  ``W > end_ms + isi_limit`` with no spike in between;
- every burst starting before ``S`` is known, where ``S`` is the earliest of ``W``, the start of
  any open burst and the earliest non-final spike; the bursting count is final before ``S``, so
  a network burst is complete once ``core_end_ms + merge_gap_ms < S``. Its extent (the earliest
  start and latest end of the bursts overlapping its core) is then known too, since every
  burst is reported whole, with its end.

The delay from a burst's last spike to its report is thus about ``window_ms + max_isi_ms`` (40 ms
by default); a network burst follows its last participating burst's report.
The per-spike work is compiled (``online_kernels.py``) and runs without the interpreter
lock, so the hub's other threads go on meanwhile; bursts and network bursts are handled
in Python (offline analysis of recorded runs should use the vectorised functions).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np

from hub.analysis import online_kernels as kernels
from hub.analysis.bursts import BURST_DTYPE, BurstParams, sort_bursts
from hub.analysis.network_bursts import NetworkBurstParams, NetworkBursts
from hub.analysis.spikes import AnalysisInputError, check_spikes


@dataclass(frozen=True)
class Burst:
    """One complete single-channel burst.

    Attributes
    ----------
    channel : int
    start_ms, end_ms : float
        Its first and last spike (absolute ms).
    n_spikes : int
    """

    channel: int
    start_ms: float
    end_ms: float
    n_spikes: int


@dataclass(frozen=True)
class NetworkBurst:
    """One complete network burst and its participating channels.

    Attributes
    ----------
    start_ms, end_ms : float
        Its extent: the earliest start and latest end of its channels' bursts.
    channels : tuple of int
        The participating channels, sorted.
    core_start_ms, core_end_ms : float
        The time at or above the threshold (as in ``network_bursts``).
    """

    start_ms: float
    end_ms: float
    channels: tuple[int, ...]
    core_start_ms: float
    core_end_ms: float

    @property
    def duration_ms(self) -> float:
        """Its extent, end minus start (ms)."""
        return self.end_ms - self.start_ms


QUEUE_START = 16  # spikes a channel's buffer holds at first (doubled when full)


class OnlineBurstDetector:
    """Incremental burst and network-burst detector; see the module docstring.

    Finds, window by window, the same bursts and network bursts as `detect_bursts` and
    `detect_network_bursts` on the whole record.

    Parameters
    ----------
    n_channels : int
        Channels of the stream (>= 1); spikes carry channel indices below it.
    burst_params : BurstParams, optional
        Default the paper's.
    network_params : NetworkBurstParams, optional
        Default the paper's.
    """

    def __init__(
        self,
        n_channels: int,
        burst_params: BurstParams | None = None,
        network_params: NetworkBurstParams | None = None,
    ):
        if int(n_channels) < 1:
            raise AnalysisInputError(f"n_channels must be >= 1, got {n_channels}")
        self.n_channels = int(n_channels)
        self.burst_params = burst_params or BurstParams()
        self.network_params = network_params or NetworkBurstParams()
        self._m = int(self.burst_params.min_spikes)
        self._window = float(self.burst_params.window_ms)
        self._isi = self.burst_params.isi_limit_ms
        self._gap = float(self.network_params.merge_gap_ms)
        self._threshold = self.network_params.min_channels(self.n_channels)
        # Per channel: spikes whose core status may change (a ring buffer each, grown when
        # full) and the open burst (open_n = 0: none). See online_kernels.py.
        n = self.n_channels
        self._q_t = np.zeros((n, QUEUE_START), np.float64)
        self._q_core = np.zeros((n, QUEUE_START), np.bool_)
        self._q_head = np.zeros(n, np.int64)
        self._q_len = np.zeros(n, np.int64)
        self._open_start = np.zeros(n, np.float64)
        self._open_last = np.zeros(n, np.float64)
        self._open_n = np.zeros(n, np.int64)
        self._watermark = -np.inf
        self._latest = -np.inf  # the watermark, or the last spike added after it if later
        # network-burst sweep state
        # heap of (time, 0 start | 1 end, channel, other end of the burst)
        self._events: list[tuple[float, int, int, float]] = []
        self._count = 0
        self._active: dict[int, int] = {}  # channel -> number of its bursts covering now
        self._open: dict[tuple[int, float], int] = {}  # (channel, start) -> bursts covering now
        self._open_end: dict[tuple[int, float], float] = {}  # ... and their end
        # candidate: [core start, core end or None while above, set(channels), extent start,
        # extent end]
        self._cand: list | None = None
        self._pending: set[int] = set()  # channels starting a burst in a candidate's gap
        self._pending_end = -np.inf  # latest end of the bursts starting in the gap
        self._bursts: list[Burst] = []
        self._network_bursts: list[NetworkBurst] = []
        # Compiled (or loaded from numba's cache) now, not at the first spikes of a run.
        self._queue(np.empty(0, np.int64), np.empty(0))
        self._advance(self._watermark, [])

    # ------------------------------------------------------------------ public API
    def feed(self, channel, t_ms, until_ms: float | None = None) -> list:
        """Add one window of spikes (absolute ms, sorted by time) and return completed events.

        Parameters
        ----------
        channel : int array[k]
            Channel index of each spike.
        t_ms : float array[k]
            Absolute spike times, sorted, none before the last spike fed.
        until_ms : float, optional
            The end of the window: the caller promises that every spike before it has now
            been fed. Default the latest spike time fed.

        Returns
        -------
        list of Burst and NetworkBurst
            The events completed, in order of completion.
        """
        t = self.add(channel, t_ms)
        # The last spike not yet behind the watermark (added now or by earlier adds).
        last = self._latest if t.size or self._latest > self._watermark else -np.inf
        w = until_ms if until_ms is not None else max(last, self._watermark)
        if w < last:
            raise AnalysisInputError(f"until_ms must be >= the last spike time {last}, got {w}")
        out: list = []
        self._advance(max(w, self._watermark), out)
        return out

    def add(self, channel, t_ms) -> np.ndarray:
        """Add spikes without completing anything.

        The next :meth:`feed`, :meth:`advance` or :meth:`flush` reports what they complete.
        Several adds and one advance cost less than as many feeds, and find the same events.

        Parameters
        ----------
        channel : int array[k]
            Channel index of each spike.
        t_ms : float array[k]
            Absolute spike times, sorted, none before the last spike added.

        Returns
        -------
        float64[k]
            The spike times as checked.
        """
        ch, t = check_spikes(channel, t_ms, self.n_channels)
        if t.size and t[0] < self._latest:
            raise AnalysisInputError(
                f"t_ms must not go back before the previous window end {self._latest}, got {t[0]}"
            )
        done = 0
        while done < t.size:
            done += self._queue(ch[done:], t[done:])
            if done < t.size:
                self._grow_queues()
        if t.size:
            self._latest = float(t[-1])
        return t

    def advance(self, until_ms: float) -> list:
        """Tell the detector that no spike before a time is still to come.

        Parameters
        ----------
        until_ms : float
            Absolute time (ms).

        Returns
        -------
        list of Burst and NetworkBurst
            The events this completes, in order of completion.
        """
        return self.feed(np.empty(0, np.uint32), np.empty(0), until_ms)

    def flush(self) -> list:
        """End of stream: complete everything still open.

        Returns
        -------
        list of Burst and NetworkBurst
            The events completed, in order of completion.
        """
        out: list = []
        self._advance(np.inf, out)
        return out

    def under_way(self) -> float | None:
        """The start of a network burst under way at the watermark, before it is complete.

        A channel counts as bursting when its open burst and the spikes of its last
        ``window_ms`` (whose core status is not final yet) make ``min_spikes`` or more; when
        the network threshold of channels are bursting, the network burst is under way
        since the threshold-th of them began. An early mark for live displays, a guess
        that the complete network burst (reported ``window_ms + max_isi_ms`` or so later)
        confirms or not.

        Returns
        -------
        float or None
            Absolute ms, or None when too few channels are bursting.
        """
        bursting = self._open_n + self._q_len >= self._m
        k = self._threshold
        if np.count_nonzero(bursting) < k:
            return None
        first = self._q_t[np.arange(self.n_channels), self._q_head]  # oldest queued spike
        start = np.where(self._open_n > 0, self._open_start, first)[bursting]
        return float(np.partition(start, k - 1)[k - 1])

    @property
    def bursts(self) -> np.ndarray:
        """All bursts reported so far, as a ``BURST_DTYPE`` array sorted like ``detect_bursts``."""
        arr = np.array(
            [(b.channel, b.start_ms, b.end_ms, b.n_spikes) for b in self._bursts], dtype=BURST_DTYPE
        )
        return sort_bursts(arr)

    @property
    def network_bursts(self) -> NetworkBursts:
        """All network bursts reported so far."""
        nbs = self._network_bursts
        return NetworkBursts(
            np.array([n.start_ms for n in nbs], dtype=np.float64),
            np.array([n.end_ms for n in nbs], dtype=np.float64),
            [np.array(n.channels, dtype=np.uint32) for n in nbs],
            np.array([n.core_start_ms for n in nbs], dtype=np.float64),
            np.array([n.core_end_ms for n in nbs], dtype=np.float64),
        )

    # ------------------------------------------------------------------ bursts
    def _queue(self, ch: np.ndarray, t: np.ndarray) -> int:
        """Queue spikes on their channels' buffers; returns how many fitted."""
        return kernels.add_spikes(
            ch, t, self._q_t, self._q_core, self._q_head, self._q_len, self._m, self._window
        )

    def _grow_queues(self) -> None:
        """Double every channel's spike buffer, each queue then starting at its first slot."""
        cap = self._q_t.shape[1]
        order = (self._q_head[:, None] + np.arange(cap)) % cap
        for name in ("_q_t", "_q_core"):
            old = np.take_along_axis(getattr(self, name), order, axis=1)
            new = np.zeros((self.n_channels, 2 * cap), old.dtype)
            new[:, :cap] = old
            setattr(self, name, new)
        self._q_head[:] = 0

    def _advance(self, w: float, out: list) -> None:
        self._watermark = w
        self._latest = max(self._latest, w)
        rows = np.empty((int(self._q_len.sum()) + self.n_channels, 4))  # room for every burst
        n, safe = kernels.advance_bursts(
            w,
            self._q_t,
            self._q_core,
            self._q_head,
            self._q_len,
            self._open_start,
            self._open_last,
            self._open_n,
            self._m,
            self._window,
            self._isi,
            rows,
        )
        for c, start, end, n_spikes in rows[:n].tolist():
            b = Burst(int(c), start, end, int(n_spikes))
            self._bursts.append(b)
            out.append(b)
            heapq.heappush(self._events, (start, 0, b.channel, end))
            heapq.heappush(self._events, (end, 1, b.channel, start))
        # Every burst starting before `safe` is known now.
        self._sweep(safe, out)

    # ------------------------------------------------------------------ network bursts
    def _sweep(self, safe: float, out: list) -> None:
        """Run the bursting-count sweep over all events before ``safe``."""
        ev = self._events
        while ev and ev[0][0] < safe:
            t, kind, c, other = heapq.heappop(ev)
            cand = self._cand
            if cand is not None and cand[1] is not None and t - cand[1] > self._gap:
                self._emit(out)
                cand = None
            if kind == 0:
                self._count += 1
                self._active[c] = self._active.get(c, 0) + 1
                key = (c, t)
                self._open[key] = self._open.get(key, 0) + 1
                self._open_end[key] = max(self._open_end.get(key, -np.inf), other)
                if cand is None:
                    if self._count == self._threshold:
                        self._cand = [
                            t,
                            None,
                            set(self._active),
                            min(s for _, s in self._open),
                            max(self._open_end.values()),
                        ]
                elif cand[1] is None:
                    cand[2].add(c)
                    cand[4] = max(cand[4], other)
                else:  # inside a candidate's gap
                    self._pending.add(c)
                    self._pending_end = max(self._pending_end, other)
                    if self._count == self._threshold:
                        cand[1] = None
                        cand[2] |= self._pending
                        cand[4] = max(cand[4], self._pending_end)
                        self._pending = set()
                        self._pending_end = -np.inf
            else:
                self._count -= 1
                n = self._active[c] - 1
                if n:
                    self._active[c] = n
                else:
                    del self._active[c]
                key = (c, other)
                n = self._open[key] - 1
                if n:
                    self._open[key] = n
                else:
                    del self._open[key]
                    del self._open_end[key]
                if cand is not None and cand[1] is None and self._count == self._threshold - 1:
                    cand[1] = t
        cand = self._cand
        if cand is not None and cand[1] is not None and safe - cand[1] > self._gap:
            self._emit(out)

    def _emit(self, out: list) -> None:
        core_start, core_end, chans, ext_start, ext_end = self._cand
        nb = NetworkBurst(ext_start, ext_end, tuple(sorted(chans)), core_start, core_end)
        self._network_bursts.append(nb)
        out.append(nb)
        self._cand = None
        self._pending = set()
        self._pending_end = -np.inf
