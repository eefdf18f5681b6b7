"""The burst observer: live burst detection beside the loop, in a process of its own.

The paper detects bursts and network bursts "on the fly". The hub's loop must never wait
for that analysis (the end of a large network burst takes tens of milliseconds of
Python), so it runs here, on the bus beside the loop. The hub forwards it the culture's
SpikeBatches it took, as the culture sent them (``ObservedSpikes``: what came in 30 ms
in realtime, in 50 ms in lockstep, one put for many steps); the observer
feeds them to :class:`~hub.live_bursts.LiveBursts` and publishes a
:class:`~hub.protocol.BurstReport` when a network burst completes, when one starts or
stops being under way, and every ``REPORT_EVERY_MS`` of run time besides (those with no
news at most every ``REPORT_GAP_S`` of wall time). The hub
records each network burst reported (a ``network_burst`` event) and counts them in its
status and the run's manifest; live displays may read the reports too.

Runs come as they come to endpoints: an ``ObserverStart`` on the observer's ``run``
queryable (the culture's channels, the detector's parameters, the run's key that seals
what goes both ways), then an ``ObserverEnd`` after the last step, answered with the
final report once the spikes of every step have been analysed. The hub starts the
observer for its run (``online.launch = "local"``), or one runs it on another machine:
``neuvision observe bursts CONFIG --connect HOST``.

The spikes are not published to the observer: the hub keeps its latest messages of them
and the observer asks for those after the last it has, one question at a time
(:mod:`hub.shelf`), every ``ASK_S`` or at once after an answer that brought a backlog. Published
(as telemetry, *drop*), they held the loop up for 0.5-0.7 s in most 1.5 s freezes of the
observer; asked for, an observer that falls behind or freezes reports later and the loop
goes on; steps it never got (fallen off the hub's shelf) are counted.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import queue
import signal
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import zenoh

from hub import stopping, wire
from hub.analysis.bursts import BurstParams
from hub.analysis.network_bursts import NetworkBurstParams
from hub.analysis.online import OnlineBurstDetector
from hub.bus import LOOP_PUBLISH, UNSERVED, HubWatch, open_session, payload_bytes
from hub.config import BusSection
from hub.live_bursts import LiveBursts
from hub.protocol import (
    BurstReport,
    Keys,
    ObservedSpikes,
    ObserverEnd,
    ObserverStart,
    ProtocolError,
    RunReply,
    SpikeBatch,
    unpack_map,
)
from hub.shelf import Asker
from hub.stopping import StopFlag

log = logging.getLogger(__name__)

NAME = "bursts"  # the observer's name in its keys (observer/bursts/...)
# A report goes out at least this often in run time (the counts in the hub's status), and
# such a report with no news no sooner than REPORT_GAP_S of wall time after the last: a
# lockstep run covers seconds of run time a second, and each report wakes the hub's loop.
REPORT_EVERY_MS = 1000.0
REPORT_GAP_S = 0.25
WAKE_S = 0.1  # the longest the observer sleeps (to see that the spikes of a run's end came)
# How often the observer asks the hub for spikes (the hub leaves them every 30-50 ms); at
# once again only after an answer that brought more than one message (a backlog: after a
# stall). Each question costs the hub ~0.3 ms of CPU in a lockstep closed loop, so one at
# once after every answer, mostly answered with nothing, cost it ~1 % of a core.
ASK_S = 0.05
ANALYSIS_NICE = 19  # the analysing thread's nice value
# An onset this close after the last network burst under way was seen is the same one.
UNDER_WAY_GAP_MS = 50.0
# ObserverEnd: how long to wait for more of the last steps' spikes (from the last that came).
END_WAIT_S = 5.0


def params_of(start: ObserverStart) -> tuple[BurstParams, NetworkBurstParams]:
    """The detector's parameters an ``ObserverStart`` carries (``online.burst`` and
    ``online.network``).

    Raises
    ------
    TypeError, ValueError
        A parameter unknown or out of range.
    """
    return BurstParams(**start.burst), NetworkBurstParams(**start.network)


class BurstObserver:
    """Serves live burst detection on a bus session, one run after another.

    Parameters
    ----------
    session : zenoh.Session
    keys : Keys
    """

    def __init__(self, session: zenoh.Session, keys: Keys):
        self.session = session
        self.keys = keys
        self.runs_done = 0
        self._events: queue.SimpleQueue = queue.SimpleQueue()
        self._run: _Run | None = None
        self._ending: tuple[zenoh.Query, int] | None = None  # ObserverEnd's query, steps
        # The detector's compiled kernels loaded now, not while the hub waits for an answer.
        OnlineBurstDetector(1)
        self._declared = [
            session.declare_queryable(keys.observer_run(NAME), self._events.put),
            session.liveliness().declare_token(keys.alive("observer", NAME)),
        ]

    def serve(self, stop: threading.Event | StopFlag, *, once: bool = False) -> bool:
        """Handle runs until ``stop`` is set (or, with ``once``, the first run ends).

        Parameters
        ----------
        stop : threading.Event or StopFlag
            Set (by a signal handler, another thread) to return.
        once : bool
            Return when the first run ends.

        Returns
        -------
        bool
            False when, with ``once``, the hub it reached left before giving it a run (it
            ended, faulted waiting for its endpoints, or runs under another session): it
            will not get one, and waiting on would be for ever; else True.
        """
        hub_left = HubWatch(self.session, self.keys) if once else None
        while not stop.is_set() and not (once and self.runs_done):
            try:
                item = self._events.get(timeout=min(WAKE_S, ASK_S))
            except queue.Empty:
                item = None
            if isinstance(item, zenoh.Query):
                self._on_query(item)
            self._take_spikes()
            if self._ending is not None and self._events.empty():
                self._try_end()
            if hub_left is not None and self._run is None and not self.runs_done and hub_left():
                log.error(
                    "burst observer: the hub it reached left without giving it a run (did "
                    "it end, or run under another session?): exiting (--once)"
                )
                return False
        self._close_run()
        return True

    def _take_spikes(self) -> None:
        """Analyse the messages of spikes that came (in one feed: its cost is mostly per
        call), and ask for more: at once after an answer that brought a backlog, else
        every ``ASK_S``."""
        run = self._run
        if run is None:
            return
        got = run.asker.take(ask=False)
        for raw in got:
            self._on_spikes(run, raw)
        run.taken_since_ask += len(got)
        now = time.monotonic()
        if (run.taken_since_ask > 1 or now >= run.asked_at + ASK_S) and run.asker.ask():
            run.asked_at, run.taken_since_ask = now, 0
        if run.live.due:
            self._publish(run, run.live.work())

    # ---------------------------------------------------------------- queries

    def _on_query(self, query: zenoh.Query) -> None:
        try:
            data = unpack_map(payload_bytes(query))
            request = (ObserverStart if "channel" in data else ObserverEnd).from_dict(data)
        except ProtocolError as exc:
            log.warning("a malformed request on %s dropped: %s", query.key_expr, exc)
            query.drop()
            return
        if isinstance(request, ObserverStart):
            self._start(query, request)
        elif self._run is None or request.run != self._run.start.run:
            self._reply(query, RunReply(ok=False, run=request.run, reason="not this run's"))
        else:
            self._ending = (query, request.steps)

    def _start(self, query: zenoh.Query, start: ObserverStart) -> None:
        if self._run is not None and self._run.start.run == start.run:  # announced again
            return self._reply(query, RunReply(ok=True, run=start.run))
        self._close_run()
        try:
            burst, network = params_of(start)
        except (TypeError, ValueError) as exc:
            return self._reply(query, RunReply(ok=False, run=start.run, reason=str(exc)))
        live = LiveBursts(start.channel, burst, network, 0.0)  # fed each message
        run = _Run(start, live)
        publisher = self.session.declare_publisher(self.keys.observer_reports(NAME), **LOOP_PUBLISH)
        run.outbox = wire.Outbox(publisher, start.key)
        # asked for (one question at a time); an answer wakes the loop
        run.asker = Asker(
            self.session,
            self.keys.observer_spikes(NAME),
            key=start.key,
            on_answer=lambda: self._events.put(run),
        )
        self._run = run
        log.info("observing run %s: %d channels", start.run, start.channel.size)
        self._reply(query, RunReply(ok=True, run=start.run))

    def _reply(self, query: zenoh.Query, message) -> None:
        wire.reply(query, message.encode())

    # ---------------------------------------------------------------- spikes

    def _on_spikes(self, run: _Run, whole: bytes) -> None:
        """One ``ObservedSpikes`` message from the hub (unsealed and whole)."""
        run_id = run.start.run
        try:
            observed = ObservedSpikes.decode(whole)
        except ProtocolError as exc:
            run.drop(str(exc))
            return
        if observed.run != run_id:
            run.drop(f"spikes of run {observed.run}")
            return
        run.last_came = time.monotonic()
        for raw in observed.batches:
            try:
                batch = SpikeBatch.decode(raw)
            except ProtocolError as exc:
                run.drop(str(exc))
                continue
            if batch.run != run_id or batch.step < run.steps:  # another run's; again
                continue
            run.lost += batch.step - run.steps  # in a message dropped on the way
            run.steps = batch.step + 1
            run.live.add(batch)

    def _publish(self, run: _Run, done: list, *, final: bool = False, missing: int = 0):
        """Report the network bursts ``done`` (the final report: all of the run's), if
        there is news: a network burst complete, one under way or no longer, or
        REPORT_EVERY_MS of run time and REPORT_GAP_S of wall time since the last report."""
        run.found.extend(done)
        onset_ms = None if final else run.live.under_way()
        until_ms = run.live.until_ms
        news = done or onset_ms != run.onset_ms
        due = (
            until_ms >= run.reported_ms + REPORT_EVERY_MS
            and time.monotonic() >= run.reported_at + REPORT_GAP_S
        )
        if not (news or due or final):
            return None
        report = run.report(run.found if final else done, onset_ms, final=final, missing=missing)
        if final:
            return dataclasses.replace(report, cpu_s=time.process_time() - run.cpu_at_start)
        run.outbox.put(report.encode())
        run.onset_ms, run.reported_ms, run.reported_at = onset_ms, until_ms, time.monotonic()
        return report

    # ---------------------------------------------------------------- the run's end

    def _try_end(self) -> None:
        query, steps = self._ending
        run = self._run
        if run.steps < steps and time.monotonic() < run.last_came + END_WAIT_S:
            return  # the last steps' spikes may still be on their way, or queued here
        missing = max(steps - run.steps, 0) + run.lost
        if missing:
            log.warning(
                "run %s: the spikes of %d step(s) never came or were dropped",
                run.start.run,
                missing,
            )
        report = self._publish(run, run.live.finish(), final=True, missing=missing)
        log.info(
            "run %s: %d steps analysed, %d network bursts; %.2f s of CPU (%.0f us a step); "
            "%d questions for spikes",
            run.start.run, run.steps, report.network_bursts, report.cpu_s,
            report.cpu_s / max(run.steps, 1) * 1e6, run.asker.asked,
        )  # fmt: skip
        self._reply(query, report)
        self._ending = None
        self._close_run()
        self.runs_done += 1

    def _close_run(self) -> None:
        run, self._run = self._run, None
        if run is not None:
            run.outbox.publisher.undeclare()


@dataclass
class _Run:
    """One run being observed."""

    start: ObserverStart
    live: LiveBursts
    outbox: wire.Outbox | None = None
    asker: Asker | None = None  # of the hub's spikes
    asked_at: float = -math.inf  # when it last asked (time.monotonic())
    taken_since_ask: int = 0  # messages taken since
    steps: int = 0  # the steps whose spikes came (in order)
    dropped: int = 0
    onset_ms: float | None = None  # the network burst under way in the last report
    reported_ms: float = 0.0  # run time of the last report
    reported_at: float = 0.0  # and when it went (time.monotonic())
    cpu_at_start: float = field(default_factory=time.process_time)
    lost: int = 0  # steps skipped in what came (a message the link dropped)
    last_came: float = field(default_factory=time.monotonic)  # when the last spikes came
    found: list = field(default_factory=list)  # every network burst reported

    def drop(self, why: str) -> None:
        self.dropped += 1
        if self.dropped <= 3:
            log.warning("a SpikeBatch refused (%s)", why)

    def report(
        self, done: list, onset_ms: float | None, *, final: bool, missing: int
    ) -> BurstReport:
        live = self.live
        return BurstReport(
            run=self.start.run,
            until_ms=live.until_ms,
            bursts=live.bursts,
            network_bursts=live.network_bursts,
            dropped=self.dropped + sum(self.asker.dropped.values() if self.asker else ()),
            nb_start_ms=[nb.start_ms for nb in done],
            nb_end_ms=[nb.end_ms for nb in done],
            nb_core_start_ms=[nb.core_start_ms for nb in done],
            nb_core_end_ms=[nb.core_end_ms for nb in done],
            nb_channels=[len(nb.channels) for nb in done],
            onset_ms=onset_ms,
            final=final,
            missing_steps=missing,
        )


@dataclass
class OnlineTally:
    """What the hub keeps of the observer's reports: the counts, the latest network
    bursts (for its status), and whether the final report came."""

    bursts: int = 0
    network_bursts: int = 0
    dropped: int = 0
    until_ms: float = 0.0
    onset_ms: float | None = None
    final: bool = False
    missing_steps: int = 0
    cpu_s: float | None = None  # the observer's, over the run (its final report)
    announced: bool = False  # the observer took the run
    lost: str = ""  # why the final report never came, if it did not
    recent: deque = field(default_factory=lambda: deque(maxlen=8))
    # The latest network bursts seen under way, [onset_ms, last seen under way (ms)] each:
    # a status (a few a second) may fall between a burst's start and end.
    under_way: deque = field(default_factory=lambda: deque(maxlen=8))
    taken: int = 0  # network bursts taken so far

    def take(self, report: BurstReport) -> list[tuple]:
        """Count one report; return the rows (``network_burst_rows``) of the network bursts
        not taken before. The final report carries every network burst of the run, so
        one that overtook an earlier report loses nothing."""
        if self.final:  # the run's analysis is complete: later reports are duplicates
            return []
        rows = report.network_burst_rows()
        if report.final:
            rows = rows[self.taken :]
        last = self.under_way[-1] if self.under_way else None
        if report.onset_ms is not None:
            if last is not None and report.onset_ms <= last[1] + UNDER_WAY_GAP_MS:
                last[1] = report.until_ms  # the same one, still under way
            else:
                self.under_way.append([report.onset_ms, report.until_ms])
        elif self.onset_ms is not None and last is not None:
            last[1] = report.until_ms  # over by then
        self.bursts, self.network_bursts = report.bursts, report.network_bursts
        self.dropped, self.until_ms = report.dropped, report.until_ms
        self.onset_ms, self.final = report.onset_ms, report.final
        self.missing_steps, self.cpu_s = report.missing_steps, report.cpu_s
        self.taken += len(rows)
        self.recent.extend(rows)
        return rows

    def counts(self) -> dict:
        """The manifest's counts of online analysis."""
        if self.final:
            state = "complete" if not self.missing_steps else "incomplete"
        else:
            state = f"incomplete: {self.lost}" if self.lost else "incomplete"
        return {
            "single_channel_bursts_online": self.bursts,
            "network_bursts_online": self.network_bursts,
            "online_analysis": state,
            "online_steps_missing": self.missing_steps,
            "online_spike_batches_refused": self.dropped,
            "online_observer_cpu_s": self.cpu_s,
        }


class _StoppedWaiting(Exception):
    """Asked to stop while still waiting for the hub."""


def main(bus: BusSection, *, once: bool = False) -> int:
    """``neuvision observe bursts``: serve on the bus until SIGINT/SIGTERM.

    Parameters
    ----------
    bus : BusSection
        Where the hub is and how to reach it (the observer takes part as ``observer``).
    once : bool
        Return when the first run ends.

    Returns
    -------
    int
        The exit status: 0, or :data:`~hub.bus.UNSERVED` when, with ``once``, the hub left
        without giving it a run.
    """
    stop = StopFlag()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if stopping.signalled_while_starting():  # and its KeyboardInterrupt was lost
        return 0
    # Zenoh's thread hands queries over through the interpreter: never wait long for it.
    sys.setswitchinterval(0.001)
    where = ", ".join(bus.connect or bus.listen)
    log.info("burst observer: connecting to the hub at %s", where)

    def waiting(where: str, waited_s: float) -> None:  # as an endpoint says it
        if stop.is_set():
            raise _StoppedWaiting
        log.info("burst observer: waiting for the hub at %s (%.0f s so far): is it started?",
                 where, waited_s)  # fmt: skip

    try:
        session = open_session(bus, listener=False, role="observer", on_wait=waiting)
    except _StoppedWaiting:
        return 0  # asked to stop before the hub was reached: nothing was opened
    try:
        observer = BurstObserver(session, bus.keys)
        # The analysis (this thread) takes only the CPU the loop leaves: it falls behind and
        # catches up. Zenoh's threads keep their priority, so the spikes are taken off the
        # link and queued meanwhile (the hub would drop what a congested link cannot take).
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), ANALYSIS_NICE)
        except (AttributeError, OSError):
            pass
        served = observer.serve(stop, once=once)
    finally:
        session.close()
    return 0 if served else UNSERVED
