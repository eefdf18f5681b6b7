"""Live burst detection: the hub's use of the online detector on the spike stream.

The paper detects bursts and network bursts "on the fly". :class:`LiveBursts`
buffers each step's :class:`~hub.protocol.SpikeBatch` and feeds the detector once
``every_ms`` of simulated time is buffered (its cost is mostly per call), mapping the
culture's channel ids to detector indices many steps at a time. Spikes go in in chunks
that can break off, keeping the rest for the next call, at a deadline or when the caller
has other work (the lockstep hub's thread breaks off for any event), so a network
burst's thousands of spikes never hold up the loop; what they complete is found in one
pass once all are in (a pass per chunk would double the cost).
:class:`BackgroundLiveBursts` runs it on a thread of its own (realtime), in the rest of
each step, since one feed at the end of a large network burst can take tens of
milliseconds of Python.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections.abc import Callable

import numpy as np

from hub.analysis.bursts import BurstParams
from hub.analysis.network_bursts import NetworkBurstParams
from hub.analysis.online import NetworkBurst, OnlineBurstDetector
from hub.protocol import Description, SpikeBatch
from hub.scheduling import Scheduling, lower_this_thread

CHUNK_SPIKES = 128  # spikes fed per detector call when working in chunks
MIN_CHUNK_SPIKES = 32  # ... and at least, when working to a deadline (unless fewer are left)
# Spikes this far behind: dropped unanalysed when working to a deadline (realtime); fed at
# once, whatever it costs, by a lockstep hub that never found idle time for them.
MAX_BACKLOG_MS = 2000.0


class LiveBursts:
    """Counts bursts and returns each network burst as it completes."""

    def __init__(
        self,
        culture: Description,
        burst: BurstParams,
        network: NetworkBurstParams,
        every_ms: float,
    ):
        self.detector = OnlineBurstDetector(culture.channel.size, burst, network)
        self.index = np.zeros(int(culture.channel.max(initial=0)) + 1, np.int64)
        self.index[culture.channel] = np.arange(culture.channel.size)
        self.every_ms = every_ms
        self.bursts = 0
        self.network_bursts = 0
        self.skipped_spikes = 0
        self._batches: list[SpikeBatch] = []  # added since the last feed
        self._left: tuple[np.ndarray, np.ndarray] | None = None  # what a feed broke off at
        self._until_ms = 0.0  # every spike before this has been buffered
        self._fed_ms = 0.0  # ... and before this fed to the detector
        self._next_ms = every_ms
        self._spike_s = 5e-6  # estimated CPU time per spike fed, refined as chunks run

    def add(self, spikes: SpikeBatch) -> None:
        """Buffer one step's spikes (kept as they came: converted many steps at a time)."""
        self._batches.append(spikes)
        self._until_ms = spikes.t1_s * 1e3

    def _take(self) -> tuple[np.ndarray, np.ndarray]:
        """Everything buffered, as detector indices and times in ms, emptying the buffer."""
        batches, self._batches = self._batches, []
        index, t_ms = self._left or (np.empty(0, np.int64), np.empty(0))
        self._left = None
        if batches:
            t0_ms = np.repeat([b.t0_s * 1e3 for b in batches], [b.t_ms.size for b in batches])
            index = np.concatenate(
                [index, self.index[np.concatenate([b.channel for b in batches])]]
            )
            t_ms = np.concatenate([t_ms, t0_ms + np.concatenate([b.t_ms for b in batches])])
        return index, t_ms

    @property
    def due(self) -> bool:
        """Whether enough simulated time is buffered to be worth a feed."""
        return bool(self._batches or self._left) and self._until_ms >= self._next_ms

    @property
    def backlog_ms(self) -> float:
        """Simulated time buffered but not yet fed to the detector."""
        return self._until_ms - self._fed_ms

    def work(
        self, deadline: float | None = None, *, pause: Callable[[], bool] | None = None
    ) -> list[NetworkBurst]:
        """Feed the buffer to the detector; return the network bursts completed.

        With a ``deadline`` (``time.monotonic()``), feed in chunks sized to end before the
        deadline (by the cost per spike of the chunks timed so far), keeping the rest;
        spikes more than MAX_BACKLOG_MS of simulated time behind are then dropped
        unanalysed (counted in ``skipped_spikes``; the record keeps them for offline
        analysis). With ``pause``, feed in chunks while ``pause()`` is False and keep the
        rest, dropping nothing: work that can wait for a caller with better things to do.
        """
        if not (self._batches or self._left):
            return []
        index, t_ms = self._take()
        if deadline is not None:
            stale = int(np.searchsorted(t_ms, self._until_ms - MAX_BACKLOG_MS))
            if stale:
                self.skipped_spikes += stale
                index, t_ms = index[stale:], t_ms[stale:]
        chunked = deadline is not None or pause is not None
        start = 0
        while start < index.size:
            size = CHUNK_SPIKES if chunked else index.size
            if deadline is not None and deadline < math.inf:
                fits = int((deadline - time.monotonic()) / self._spike_s)
                size = min(size, fits) if fits >= min(MIN_CHUNK_SPIKES, index.size - start) else 0
            if size < 1 or (pause is not None and pause()):
                self._left = (index[start:], t_ms[start:])
                return []
            stop = min(start + size, index.size)
            t0 = time.thread_time()
            # Chunks are only added: what they complete is found in one pass at the end.
            self.detector.add(index[start:stop], t_ms[start:stop])
            self._fed_ms = t_ms[stop - 1]
            if deadline is not None and stop - start >= MIN_CHUNK_SPIKES:
                # Running estimate of the cost of a spike, in CPU time (a chunk held up by
                # other threads says nothing of the next one's cost), from chunks large
                # enough for the cost of the call itself to matter little.
                spike_s = (time.thread_time() - t0) / (stop - start)
                self._spike_s = 0.8 * self._spike_s + 0.2 * spike_s
            start = stop
        # A spike stamped at the window's very end may round a hair past it.
        until_ms = max(self._until_ms, t_ms[-1]) if t_ms.size else self._until_ms
        done: list[NetworkBurst] = []
        self._count(self.detector.advance(until_ms), done)
        self._fed_ms = self._until_ms
        self._next_ms = self._until_ms + self.every_ms
        return done

    def finish(self) -> list[NetworkBurst]:
        """End of the run: feed what is buffered and complete every burst still open (as
        offline detection does at the end of a record); return the network bursts
        completed."""
        done = self.work()
        self._count(self.detector.flush(), done)
        return done

    def _count(self, events: list, done: list[NetworkBurst]) -> None:
        for event in events:
            if isinstance(event, NetworkBurst):
                self.network_bursts += 1
                done.append(event)
            else:
                self.bursts += 1


class BackgroundLiveBursts:
    """:class:`LiveBursts` on a thread of its own: the loop hands each step's spikes over and
    collects the network bursts completed, so analysis never holds up a step. The thread
    runs just below the loop's priority (:func:`~hub.scheduling.lower_this_thread`) and
    works only until the ``until`` given with the spikes (the next step's start): a
    thread holding the interpreter when the loop's thread wakes would delay the step by up
    to the interpreter's switch interval. Counters are read from ``live``."""

    def __init__(self, live: LiveBursts, scheduling: Scheduling | None = None):
        self.live = live
        self.scheduling = scheduling or Scheduling("normal")
        self._in: queue.SimpleQueue = queue.SimpleQueue()
        self._out: queue.SimpleQueue = queue.SimpleQueue()
        self._failure: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="live-bursts", daemon=True)
        self._thread.start()

    def add(self, spikes: SpikeBatch, until: float = math.inf) -> None:
        """Hand one step's spikes over; analysis may run until ``until`` (monotonic)."""
        self._in.put((spikes, until))

    def completed(self) -> list[NetworkBurst]:
        """The network bursts completed since the last call."""
        out = []
        while True:
            try:
                out.append(self._out.get_nowait())
            except queue.Empty:
                return out

    def close(self, timeout_s: float = 30.0) -> list[NetworkBurst]:
        """Analyse what is left, stop the thread, return the last network bursts (or
        raise what ended the thread)."""
        self._in.put(None)
        self._thread.join(timeout_s)
        if self._failure is not None:
            raise self._failure
        return self.completed()

    def _run(self) -> None:
        try:
            self._analyse()
        except BaseException as exc:  # raised again by close()
            self._failure = exc
            raise

    def _analyse(self) -> None:
        lower_this_thread(self.scheduling)
        live = self.live
        while (item := self._in.get()) is not None:
            spikes, until = item
            live.add(spikes)
            if live.due:  # chunked, and spikes too far behind are dropped and counted
                for nb in live.work(deadline=until):
                    self._out.put(nb)
        for nb in live.finish():
            self._out.put(nb)
