"""The hub: the timing-authoritative step loop of ARCHITECTURE.md.

At step k the hub sends the body its motor command (decoded from the culture's spikes of
step k−1) and the culture its stimulation (coded from the body's sensors of step k−1), then
collects both replies for step k. When each step's inputs go and how long its replies are
waited for is the scheduler's: :class:`~hub.lockstep.Lockstep` (as fast as the endpoints
go) or :class:`~hub.realtime.Realtime` (on a wall-clock schedule, with deadlines). The
scheduler and the hub meet in :mod:`hub.steps`.

:class:`Hub` here is a run's life (set-up, the steps, close-up) and the loop's thread: the
events from the bus, which Zenoh's callbacks queue for it (lockstep takes the replies in
the threads they come on), and the loop's chores. Its parts: the bus (:mod:`hub.link`);
the endpoints awaited, described and given the run (:mod:`hub.participants`, asked through
:mod:`hub.roster`); each input sent and each reply taken (:mod:`hub.traffic`: checked by
:mod:`hub.replies`, judged by :mod:`hub.ledger`); each step's inputs (:mod:`hub.policy`);
who comes and goes (:mod:`hub.presence`); control requests (:mod:`hub.control`); status,
views and progress (:mod:`hub.telemetry`); the burst observer's run (:mod:`hub.online`);
the run's figures (:mod:`hub.report`).
"""

from __future__ import annotations

import logging
import queue
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from hub.analysis.bursts import BurstParams
from hub.analysis.network_bursts import NetworkBurstParams
from hub.bus import BusError, open_session
from hub.config import ConfigError, ExperimentConfig
from hub.control import Control
from hub.errors import HubError
from hub.launch import LocalProcess, stop_local_endpoints
from hub.ledger import Ledger
from hub.link import HubLink
from hub.lockstep import Lockstep
from hub.manifest import RunManifest
from hub.online import PARTICIPANT as OBSERVER
from hub.online import OnlineAnalysis
from hub.participants import Participants
from hub.policy import InputPolicy, SchemeError
from hub.presence import Presence
from hub.protocol import BurstReport, Description, HubStatus, ProtocolError
from hub.realtime import Realtime
from hub.record import Recorder, RecordError
from hub.report import LoopTimes
from hub.report import counts as run_counts
from hub.roster import Roster
from hub.scheduling import CpusAwake, Placement, check_cpus, place_threads, restore_placement
from hub.steps import INTERRUPTED, STOPPED_BY_CONTROL, Standing, StoppedBeforeSteps, ready_for_steps
from hub.telemetry import Progress, Telemetry
from hub.traffic import Traffic

__all__ = ["INTERRUPTED", "STOPPED_BY_CONTROL", "Hub", "Progress", "RunResult"]

log = logging.getLogger(__name__)

# The schedulers of the steps, by ``loop.mode``.
SCHEDULERS = {"lockstep": Lockstep, "realtime": Realtime}
# At the run's end, how long the hub waits for a live display to ask for its last view.
LAST_VIEW_WAIT_S = 1.0
# What ends a run as a stop or a fault, the hub going on to close it up; anything else (a
# crash, KeyboardInterrupt) is raised again once the run is closed up.
ENDS_A_RUN = (StoppedBeforeSteps, HubError, ConfigError, SchemeError, RecordError)


@dataclass
class RunResult:
    """How a run ended (what ``Hub.run`` returns; its manifest says the same): the outcome
    and why, the steps done, the loop's timing and the counts, the run folder and the
    endpoints' descriptions."""

    outcome: str  # completed | stopped | interrupted | fault
    reason: str
    steps: int
    timing: dict
    counts: dict
    run_dir: Path | None = None
    descriptions: dict[str, Description] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """Whether the run ended as asked (completed, or stopped or interrupted by its
        user), not by a fault."""
        return self.outcome in ("completed", "stopped", "interrupted")


class Hub:
    """Runs one experiment: waits for its endpoints, steps the loop, records it.

    Parameters
    ----------
    cfg : ExperimentConfig
        The validated experiment. The run keeps, and its manifest records, the config as
        each endpoint's kind resolves it (``cfg.resolved()``: the culture's and the world's
        contents in place), whoever made the hub.
    run_dir : Path or None
        Where to write the record and manifest (None: neither; with ``record.enabled``
        false, the manifest only).
    progress : callable or None
        Called with a :class:`~hub.telemetry.Progress` a few times a second.
    wait_for_view_s : float
        Hold the first step until a live display watches ``hub/view``, at most this long
        (``neuvision run --dashboard``); 0: start at once.

    Raises
    ------
    ConfigError
        An endpoint's kind or params do not resolve.
    """

    def __init__(
        self,
        cfg: ExperimentConfig,
        run_dir: Path | None = None,
        progress: Callable[[Progress], None] | None = None,
        wait_for_view_s: float = 0.0,
    ):
        # Resolving is idempotent, and a config resolved already resolves in milliseconds.
        self.cfg = cfg = cfg.resolved()
        self.run_dir = Path(run_dir) if run_dir else None
        self.wait_for_view_s = wait_for_view_s
        self.run_id = uuid.uuid4().hex  # in every message of the run
        self.standing = Standing()
        self.inbox: queue.SimpleQueue = queue.SimpleQueue()  # events for the loop's thread
        self.post = self.inbox.put
        self.recorder: Recorder | None = None  # the run's record, once its folder is open
        self.link: HubLink | None = None  # the hub's declarations, once the session opens
        self.inputs: InputPolicy | None = None  # each step's inputs, once described
        self.cpus_awake: CpusAwake | None = None  # whether idle CPUs were kept awake
        self.placement = Placement()  # the CPUs the hub's threads are kept on (loop.cpus)
        self.ledger = Ledger(on_event=self.record_event)
        self.times = LoopTimes.for_run(cfg.loop.mode, cfg.loop.period_ms, cfg.n_steps)
        self._flush_s = cfg.record.flush_s  # the loop's thread wakes at least this often
        self.online = (  # live burst detection by the burst observer
            OnlineAnalysis(cfg, self.run_id, self.record_event, lambda: self.scheduler.k)
            if cfg.online.enabled
            else None
        )
        self.participants = Participants(
            cfg, self.run_id, self.standing, self.online, self.record_event
        )
        self.descriptions = self.participants.descriptions
        self.traffic = Traffic(
            cfg, self.run_id, self.standing, self.ledger, self.participants.checker, self.times
        )
        self.traffic.online = self.online
        # what the scheduler calls on every step, bound once (hub.steps.LoopPort)
        self.send, self.resend_unanswered = self.traffic.send, self.traffic.resend_unanswered
        self._take = self.traffic.take
        self.scheduler = SCHEDULERS[cfg.loop.mode](
            self, self.standing, self.ledger, self.times, cfg.loop, cfg.n_steps
        )
        self.telemetry = Telemetry(
            cfg, self.run_id, self.standing, self.scheduler, self.ledger, self.times,
            self.traffic, self.online.tally if self.online else None, progress,
        )  # fmt: skip
        self.presence = Presence(
            cfg, self.standing, self.ledger, self.scheduler, self.online,
            self.participants.readmit, self.record_event,
        )  # fmt: skip
        self.control = Control(
            self.standing, self.times, self.ledger, self.telemetry.status, cfg.to_dict,
            self.participants.hold, self.record_event,
        )  # fmt: skip

    def request_stop(self, reason: str = INTERRUPTED) -> None:
        """Stop after the current step (thread- and signal-safe)."""
        self.inbox.put(("stop", reason))

    def run(self) -> RunResult:
        """Run the experiment to its end, a stop, or a fault; always close it up."""
        cfg = self.cfg
        check_cpus("loop.cpus", cfg.loop.cpus)  # a config error before anything is written
        manifest = RunManifest(cfg, self.run_id, self.run_dir)
        self.recorder = self.traffic.recorder = manifest.begin()
        # Started first: it builds its detector while the endpoints build their models.
        online = self.online
        observer = online.start(self.run_dir if self.recorder else None) if online else None
        # Before Zenoh starts its threads, which inherit the placement.
        self.placement = place_threads("loop.cpus", cfg.loop.cpus)
        if self.placement.reason:
            log.warning("loop.cpus not applied: %s", self.placement.reason)
        session = self._open_session(manifest, observer)
        outcome, reason = "completed", ""
        try:
            self.attach(session)
            self.participants.await_all(self._next_event)
            self.participants.describe_all()
            self._await_display()
            self.prepare(self.descriptions)
            if self.online is not None:  # subscribed before the culture may send a spike
                self.online.announce(self.link, cfg.n_steps, self.descriptions["culture"].channel)
            self.participants.announce_all()
            self.record_event("start", mode=cfg.loop.mode, n_steps=cfg.n_steps)
            self._steps()
            if self.standing.stop_reason:
                outcome, reason = self.standing.stopped_outcome(), self.standing.stop_reason
        except BaseException as exc:
            outcome, reason = self._ended_by(exc)
            if not isinstance(exc, ENDS_A_RUN):
                raise  # once closed up
        finally:
            try:
                result = self._close_up(manifest, outcome, reason)
            finally:
                # whatever fails in the close-up, the session closes (its callback threads
                # would keep the process from ever exiting) and the burst observer stops
                session.close()
                self._release(observer)
        return result

    def attach(self, session: zenoh.Session) -> None:
        """Declare the run on ``session``: the inputs' publishers, the replies'
        subscription, liveliness, control and status (:class:`~hub.link.HubLink`), the bus's
        events going to the scheduler (``Scheduler.deliver``)."""
        participants = self.participants
        self.link = HubLink(
            session, self.cfg.bus.keys, participants.ids, participants.run_keys,
            self.scheduler.deliver,
        )  # fmt: skip
        self.traffic.link = self.telemetry.link = self.link
        participants.roster = Roster(self.cfg, self.link, self.recorder)

    def prepare(self, descriptions: dict[str, Description]) -> None:
        """Build what the loop needs of the endpoints' descriptions: the input policy
        (coding, decoding, limits); and check the live burst detector's settings.
        :meth:`run` does this once every endpoint has described itself.

        Raises
        ------
        SchemeError, ConfigError
            A scheme does not fit the endpoints, or the online analysis's settings are bad.
        """
        try:
            self.inputs = InputPolicy(
                self.cfg, descriptions["body"], descriptions["culture"], self.run_id,
                on_refused=lambda scheme, why: self.ledger.drop(scheme, "limit", why),
            )  # fmt: skip
        except ConfigError as exc:  # the params were checked before; this needs the endpoints
            raise ConfigError(
                f"the schemes do not fit the endpoints' descriptions: {exc}"
            ) from None
        if self.cfg.online.enabled:
            _check_online(self.cfg)

    def status(self) -> HubStatus:
        """The run's status now (what ``hub/status`` carries)."""
        return self.telemetry.status()

    def record_event(self, name: str, **details) -> None:
        """Record something the hub noticed or did (an ``ev`` frame; none without a record)."""
        if self.recorder:
            self.recorder.event(name, **details)

    # ================================================================ the loop's thread

    def wait_event(self, until: float) -> tuple | None:
        """The next event, waiting at most until ``until`` (monotonic), the next status, or
        a flush of the record is due; None if none came."""
        now = time.monotonic()
        timeout = min(until - now, self.telemetry.status_due_at - now, self._flush_s)
        t0 = time.perf_counter()
        try:
            return self.inbox.get(timeout=max(timeout, 0.0))
        except queue.Empty:
            return None
        finally:
            self.times.waiting_s += time.perf_counter() - t0
            self.presence.note_wake()

    def drain(self) -> None:
        """Handle every event waiting for the loop's thread."""
        while True:
            try:
                item = self.inbox.get_nowait()
            except queue.Empty:
                return
            self.handle(item)

    def handle(self, item: tuple) -> None:
        """Act on one event (the tuples of :mod:`hub.link`, and the hub's own)."""
        kind = item[0]
        if kind == "rx":
            self._take(*item[1:])
        elif kind == "refused":
            self.traffic.refused(*item[1:])
        elif kind == "alive":
            self.presence.seen(*item[1:])
        elif kind == "control":
            self.control.answer(item[1])
        elif kind == "status":  # an observer asks for the run's status (read-only)
            self.control.answer_status(item[1])
        elif kind == "report":  # the burst observer's, unsealed already
            try:
                report = BurstReport.decode(item[1])
            except ProtocolError as exc:
                self.ledger.drop("observer", exc.kind, str(exc))
            else:
                if self.online is not None:
                    self.online.take_report(report)
        elif kind == "report_refused":  # not sealed by the observer of this run
            self.ledger.drop("observer", item[1], item[2])
        elif kind == "stop":
            self.standing.stop_reason = self.standing.stop_reason or item[1]
        # "wake": nothing to do but look at the state

    def tick(self) -> None:
        """The loop's chores that are due: the deadline of an endpoint awaited back, an
        endpoint silent too long, the status (and progress), the record's flush."""
        if self.standing.awaited:
            self.presence.check_deadlines()
        if self.ledger.silent_since:
            self.presence.check_silent()
        now = time.monotonic()
        if now >= self.telemetry.status_due_at:
            self.telemetry.publish_status(now)
        if self.recorder:
            self.recorder.tick()

    def share(self, now: float, *, view: bool = True) -> None:
        """After a step: the culture's spikes for the burst observer and, with ``view``, a
        view for live displays, each if due.

        Parameters
        ----------
        now : float
            The time (monotonic, s) they are due by.
        view : bool
            Whether a view may be built now (realtime: not when the next step is near).
        """
        online = self.online
        if online is not None and online.pending and now - online.forwarded_at >= online.forward_s:
            online.forward()
        if view and now >= self.telemetry.view_due_at:
            self.telemetry.publish_view(now)

    @property
    def view_due_at(self) -> float:
        """When (monotonic) the next view for live displays falls due."""
        return self.telemetry.view_due_at

    def _next_event(self, until: float) -> None:
        """Handle one event, waiting at most until ``until``; the chores if none came (the
        waits before and after the steps)."""
        item = self.wait_event(until)
        if item is None:
            self.tick()
            self.share(time.monotonic())
        else:
            self.handle(item)

    # ================================================================ the run's life

    def _open_session(self, manifest: RunManifest, observer: LocalProcess | None) -> zenoh.Session:
        """The hub's Zenoh session (its router); one that does not open ends the run."""
        try:
            return open_session(self.cfg.bus, listener=True)
        except BaseException as exc:
            self._release(observer)
            # the run folder exists: close it as a fault that says why (an address taken),
            # not "running" for ever
            reason = str(exc) if isinstance(exc, BusError) else f"hub crashed: {exc!r}"
            if isinstance(exc, KeyboardInterrupt):
                reason = INTERRUPTED
            outcome = "interrupted" if reason == INTERRUPTED else "fault"
            manifest.close(self.recorder, outcome, reason, steps=0)
            raise

    def _await_display(self) -> None:
        """Hold the first step until a live display asks for views (``hub/view``), at most
        ``wait_for_view_s``: the page then shows the run from its first step, and the
        display's start-up (its imports, reading the world it draws) is not paid during the
        steps. Before the run is announced, so that no endpoint's clock has started."""
        if self.wait_for_view_s <= 0 or not self.cfg.loop.view_hz:
            return
        start = time.monotonic()
        deadline = start + self.wait_for_view_s
        log.info("waiting for the dashboard to watch (at most %g s)", self.wait_for_view_s)
        while not self.link.view_observed():
            self.standing.check_stop("the dashboard")
            if time.monotonic() >= deadline:
                log.warning(
                    "the dashboard did not watch within %g s: the run starts without it",
                    self.wait_for_view_s,
                )
                self.record_event("view_wait", watched=False, waited_s=self.wait_for_view_s)
                return
            self._next_event(min(deadline, time.monotonic() + 0.05))
        self.record_event("view_wait", watched=True, waited_s=time.monotonic() - start)
        self.telemetry.view.watch(True)  # gather from the first step

    def _steps(self) -> None:
        """Run the steps (ARCHITECTURE.md, "The loop"), timed by the scheduler."""
        self.standing.state = "running"
        with ready_for_steps(self.cfg.loop.keep_cpus_awake) as self.cpus_awake:
            self.presence.steps_start()
            self.scheduler.run(self.inputs, self.descriptions)

    def _ended_by(self, exc: BaseException) -> tuple[str, str]:
        """The outcome of a run that ``exc`` ended, and why; said in the log and the record."""
        if isinstance(exc, StoppedBeforeSteps):
            log.info("%s before the first step", self.standing.stop_reason)
            return self.standing.stopped_outcome(), self.standing.stop_reason
        if isinstance(exc, (HubError, ConfigError, SchemeError)):
            log.error("%s", exc)
            self.record_event("fault", reason=str(exc))
            return "fault", str(exc)
        if isinstance(exc, RecordError):  # a full disk, the folder gone: unrecorded, it stops
            log.error("%s", exc)
            self.recorder.abandon()
            self.recorder = self.traffic.recorder = None
            return "fault", str(exc)
        if isinstance(exc, KeyboardInterrupt):
            return "interrupted", "KeyboardInterrupt"
        return "fault", f"hub crashed: {exc!r}"

    def _close_up(self, manifest: RunManifest, outcome: str, reason: str) -> RunResult:
        """Whatever ended the run: the robot stopped, the endpoints told and asked for their
        counters, the burst observer's final report, the last view and status, the record
        and manifest closed (a record not closed makes the run a fault).

        Each part is tried on its own: one that fails (a bug) is logged with its traceback
        and makes the run a fault that names it, and the rest is still done -- the manifest
        always closed, never left saying "running".
        """
        failed: list[str] = []

        def attempt(what: str, part: Callable, *args, **kwargs):
            try:
                return part(*args, **kwargs)
            except Exception as exc:
                log.exception("closing the run: %s failed", what)
                failed.append(f"{what} failed ({type(exc).__name__}: {exc})")
                return None

        if self.link is not None and self.descriptions.get("body"):
            # sent whether or not the body looks alive: a frozen body gets it if it comes
            # back in time (it also stops itself: its input timeout, the hub's liveliness)
            attempt("the body's final stop", self.traffic.stop_body, self._next_event)
        # those alive, whatever the outcome
        endpoints = attempt("the endpoints' counters", self.participants.manifest_entries)
        attempt("telling the endpoints the run ended", self.participants.end, outcome)
        if self.online is not None:
            end_observer, alive = self.online.end, self.standing.alive
            attempt("the burst observer's final report", end_observer, self.scheduler.k_done,
                    there=lambda: OBSERVER in alive, take_waiting=self._take_reports)  # fmt: skip
        attempt("the last view", self.telemetry.publish_view, time.monotonic())
        steps, ledger, tally = self.scheduler.k_done, self.ledger, self.telemetry.tally
        timing = attempt(
            "the run's timing", self.times.report, steps, self.scheduler.scheduling,
            self.cpus_awake,
        )  # fmt: skip
        counts = attempt(
            "the run's counts", run_counts, tally, ledger.late, ledger.missed, ledger.dropped
        )
        if failed:
            why = "; ".join(failed)
            outcome, reason = "fault", f"{reason}; {why}" if outcome == "fault" else why
        self.standing.state = "stopped"
        self.standing.ended = (outcome, reason)  # said in the final status, for observers
        attempt("the final status", self.telemetry.publish_status, time.monotonic(), progress=False)
        unrecorded = manifest.close(
            self.recorder, outcome, reason, steps=steps, timing=timing or {},
            counts=counts or {}, rejoins=self.presence.rejoins, endpoints=endpoints or {},
        )  # fmt: skip
        if unrecorded and outcome != "fault":  # the record is not whole: a fault
            outcome, reason = "fault", unrecorded
        if self.link is not None and self.link.view_observed():
            self.link.views.wait_had(LAST_VIEW_WAIT_S)  # a live display's last view
        return RunResult(
            outcome, reason, steps, timing or {}, counts or {}, self.run_dir, self.descriptions
        )

    def _take_reports(self) -> None:
        """After the steps: handle the burst observer's reports waiting, and its going or
        return (whether it is there to be asked for its final report; recorded); nothing
        else waiting matters to the run any more (an endpoint's end, a late reply)."""
        while not self.inbox.empty():  # this thread alone takes from the queue
            item = self.inbox.get_nowait()
            if item[0] in ("report", "report_refused") or (
                item[0] == "alive" and self.cfg.bus.keys.parse_alive(item[1]) == OBSERVER
            ):
                self.handle(item)

    def _release(self, observer: LocalProcess | None) -> None:
        """The CPUs as they were before the run, and the burst observer it started stopped."""
        restore_placement(self.placement)
        if observer is not None:
            stop_local_endpoints([observer])


def _check_online(cfg: ExperimentConfig) -> None:
    """Raise :class:`ConfigError` naming ``online.burst`` or ``online.network`` if the live
    burst detector's parameters are bad."""
    for name, kind in (("burst", BurstParams), ("network", NetworkBurstParams)):
        try:
            kind(**getattr(cfg.online, name))
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"online.{name}: {exc}") from None
