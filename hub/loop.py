"""The hub: the timing-authoritative step loop of ARCHITECTURE.md.

At step k the hub sends the body its motor command (decoded from the culture's
spikes of step k−1) and the culture its stimulation (coded from the body's
sensors of step k−1), then collects both replies for step k. In ``lockstep``
mode the next step starts when both are in; in ``realtime`` mode steps start
on a wall-clock schedule and a reply that misses its deadline is late: the
configured policy stands in for it and it is counted.

Zenoh callbacks enqueue events for the loop's thread, with one exception: during
lockstep steps each reply is taken, and the input that depends on it sent, by the
thread that received it, under the loop's lock (a hand-over to the loop's thread would
put a thread wake-up on every step's critical path). Everything that touches the loop's
state, recording included, holds that lock, so the loop keeps one order of events.

The parts: :class:`Hub` here sets a run up (endpoints, descriptions, the run's
announcement), handles events and closes up; the two schedulers,
:class:`~hub.lockstep.Lockstep` and :class:`~hub.realtime.Realtime`, keep the steps' own
state and call the hub's loop services (``send``, ``wait_event``, ``handle``, ``tick``);
what crosses the bus goes through :mod:`hub.link`, and the questions to the endpoints
(describe, take the run, pause, its end) through :mod:`hub.roster`; each step's inputs come from
:mod:`hub.policy`, each reply is checked by :mod:`hub.replies` and judged by
:mod:`hub.ledger`; the burst observer's run is :mod:`hub.online`'s, and the run's
figures are kept by :mod:`hub.report`.
"""

from __future__ import annotations

import gc
import logging
import math
import queue
import sys
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from hub import wire
from hub.analysis.bursts import BurstParams
from hub.analysis.network_bursts import NetworkBurstParams
from hub.bus import BusError, open_session, payload_bytes
from hub.config import ConfigError, ExperimentConfig
from hub.errors import EndpointDied, HubError
from hub.launch import LocalProcess, stop_local_endpoints
from hub.ledger import Ledger
from hub.link import HubLink
from hub.lockstep import Lockstep
from hub.online import PARTICIPANT as OBSERVER
from hub.online import OnlineAnalysis
from hub.policy import InputPolicy, SchemeError
from hub.protocol import (
    ROLES,
    BurstReport,
    ControlReply,
    ControlRequest,
    Description,
    HubStatus,
    Message,
    MotorCommand,
    ProtocolError,
    RunStart,
    StepWindow,
)
from hub.realtime import Realtime
from hub.record import (
    Recorder,
    RecordError,
    experiment_text,
    host,
    utc_now,
    versions,
    write_manifest,
)
from hub.replies import ReplyChecker
from hub.report import LoopTimes, counts, steps_share
from hub.roster import Roster, check_fits_loop
from hub.scheduling import (
    CpusAwake,
    Placement,
    Scheduling,
    check_cpus,
    hold_cpus_awake,
    place_threads,
    raise_threads,
    restore_placement,
    restore_threads,
)
from hub.view import ObserverView

log = logging.getLogger(__name__)

# Realtime: a view for live displays is built after a step, and only this long or more before
# the next step's start (else after a later step), so that it never delays a step.
VIEW_GUARD_S = 1e-3
# Lockstep: a view goes from the reply thread after a step (Lockstep._advance); the loop's
# thread sends one only when the steps stand still this long past its time (paused, an
# endpoint awaited). Woken at the view rate, it took the loop's lock from the replies
# thirty times a second (docs/measurements/dashboard-cost.md).
VIEW_STALL_S = 0.1
# How often the hub looks whether anyone asks for views, while no one does.
LOOK_S = 0.25
# At the run's end, how long the hub waits for a live display to ask for its last view.
LAST_VIEW_WAIT_S = 1.0
# The longest a thread holds the interpreter while another wants it during the steps.
# Python's default, 5 ms, would let the recorder or a status hold up a step start
# (realtime) or keep Zenoh's callback from handing the loop a reply (both modes).
GIL_SWITCH_S = 2e-4


# Why a run ended before its last step, when the user asked: a signal, or ``ctl stop``.
INTERRUPTED, STOPPED_BY_CONTROL = "interrupted", "stopped by control"


class StoppedBeforeSteps(Exception):
    """A stop asked for by the user (a signal, ``ctl stop``) before the first step: the run
    ends as ``interrupted`` or ``stopped``, as the same stop during the steps does."""


@dataclass
class Progress:
    """What a progress display needs, given after each step."""

    step: int
    n_steps: int
    t_s: float
    wall_s: float
    steps_per_s: float
    late_steps: int
    state: str


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
        return self.outcome in ("completed", "stopped", "interrupted")


class Hub:
    """Runs one experiment: waits for its endpoints, steps the loop, records it.

    Parameters
    ----------
    cfg : ExperimentConfig
        The validated experiment.
    run_dir : Path or None
        Where to write the record and manifest (None: neither; with ``record.enabled``
        false, the manifest only).
    progress : callable or None
        Called with a :class:`Progress` a few times a second.
    wait_for_view_s : float
        Hold the first step until a live display watches ``hub/view``, at most this long
        (``neuvision run --dashboard``); 0: start at once.
    """

    def __init__(
        self,
        cfg: ExperimentConfig,
        run_dir: Path | None = None,
        progress: Callable[[Progress], None] | None = None,
        wait_for_view_s: float = 0.0,
    ):
        self.cfg = cfg
        self.wait_for_view_s = wait_for_view_s
        self.keys = cfg.bus.keys
        self.run_dir = Path(run_dir) if run_dir else None
        self.progress = progress
        self.ids = {role: cfg.endpoint(role).id for role in ROLES}
        self.input_key = {role: self.keys.input(role, i) for role, i in self.ids.items()}
        self.output_key = {role: self.keys.output(role, i) for role, i in self.ids.items()}
        self.inbox: queue.SimpleQueue = queue.SimpleQueue()
        # The run's identity: its id goes into every message, and each endpoint gets a key
        # of its own that seals what the hub and it send each other (hub/wire.py).
        self.run_id = uuid.uuid4().hex
        self.run_keys = {role: wire.new_key() for role in ROLES}
        self.link: HubLink | None = None  # the hub's declarations, once the session opens
        self.period_s = cfg.loop.period_ms / 1e3
        self.checker = ReplyChecker(self.run_id, self.period_s)
        self.state = "waiting"
        self.ended: tuple[str, str] | None = None  # (outcome, reason) once stopped
        self.alive: set[tuple[str, str]] = set()
        # What each role owes and what came (the verdicts and their counts).
        self.ledger = Ledger(on_event=self.record_event)
        self.descriptions: dict[str, Description] = {}
        self.participants: dict[str, dict] = {}  # each endpoint's host, clock offset
        # policy.rejoin_s: role -> (when its liveliness vanished, the step then); and the
        # rejoins so far (the manifest's `rejoins`)
        self.gone: dict[str, tuple[float, int]] = {}
        self.rejoins: list[dict] = []
        # lockstep: the inputs each role has not answered yet, by step (sent again to an
        # endpoint that rejoins)
        self.unanswered: dict[str, dict[int, bytes]] = {role: {} for role in ROLES}
        self._keep_unanswered = cfg.policy.rejoin_s > 0
        self._start_unix_s: float | None = None  # as announced to the endpoints
        # when each role's input of each step was put, for its reply's round trip
        # (plain lists: a numpy scalar read and NaN test cost microseconds a reply)
        self.n_steps = cfg.n_steps
        self._put_at = {role: [math.nan] * self.n_steps for role in ROLES}
        self._last_round_trip_ms: dict[str, float] = {}  # the latest, for observers
        self.stop_reason: str | None = None  # why the run must end before its last step
        self._next_status = 0.0
        # What live displays get on hub/view (hub/view.py), while anyone asks for them.
        self.view = ObserverView(self.run_id)
        self._next_view = 0.0
        n = cfg.n_steps
        self.times = LoopTimes.for_run(cfg.loop.mode, cfg.loop.period_ms, n)
        self.recorder: Recorder | None = None
        # Live burst detection by the burst observer (hub/online.py; None with
        # online.enabled = false)
        self.online: OnlineAnalysis | None = (
            OnlineAnalysis(cfg, self.run_id, self.record_event, lambda: self.k)
            if cfg.online.enabled
            else None
        )
        self.roster: Roster | None = None  # the endpoints, asked over the link (attach)
        self.scheduling: Scheduling | None = None  # realtime: what the hub's threads got
        self.cpus_awake: CpusAwake | None = None  # whether idle CPUs were kept awake
        self.placement = Placement()  # the CPUs the hub's threads are kept on (loop.cpus)
        # Lockstep: replies are taken in the threads they arrive on (``scheduler.direct``).
        self.lock = threading.Lock()  # held by whatever touches the loop's state then
        self.scheduler = Lockstep(self) if cfg.loop.mode == "lockstep" else Realtime(self)
        # The loop's thread wakes at least every record.flush_s; a longer gap means the
        # hub itself did not run (frozen, starved): (when it ended, how long it was).
        self._last_wake = time.monotonic()
        self._stall: tuple[float, float] = (-math.inf, 0.0)

    # ================================================================ public

    @property
    def k(self) -> int:
        """The step under way."""
        return self.scheduler.k

    @property
    def k_done(self) -> int:
        """The steps whose every reply is in (or stood in for)."""
        return self.scheduler.k_done

    def request_stop(self, reason: str = INTERRUPTED) -> None:
        """Stop after the current step (thread- and signal-safe)."""
        self.inbox.put(("stop", reason))

    def run(self) -> RunResult:
        """Run the experiment to its end, a stop, or a fault; always close up."""
        cfg = self.cfg
        check_cpus("loop.cpus", cfg.loop.cpus)  # a config error before anything is written
        manifest = {
            "format": "neuvision-run",
            "v": 1,
            "name": cfg.experiment.name,
            "seed": cfg.experiment.seed,
            "run_id": self.run_id,
            "config_source": cfg.source,
            "config_text": experiment_text(cfg.source),
            "config": cfg.to_dict(),
            "versions": versions(),
            "hosts": {"hub": host()},
            "start_utc": utc_now(),
            "outcome": "running",
        }
        if self.run_dir:  # record.enabled = false: the manifest only, no messages
            if cfg.record.enabled:
                self.recorder = Recorder(self.run_dir, flush_s=cfg.record.flush_s)
            write_manifest(self.run_dir, manifest)
        # Started first: it builds its detector while the endpoints build their models.
        observer = (
            self.online.start(self.run_dir if self.recorder else None) if self.online else None
        )
        # Before Zenoh starts its threads, which inherit the placement.
        self.placement = place_threads("loop.cpus", cfg.loop.cpus)
        if self.placement.reason:
            log.warning("loop.cpus not applied: %s", self.placement.reason)
        try:
            session = open_session(cfg.bus, listener=True)
        except BaseException as exc:
            self._release(observer)
            # the run folder exists: close it as a fault that says why (an address taken),
            # not "running" for ever
            reason = str(exc) if isinstance(exc, BusError) else f"hub crashed: {exc!r}"
            if isinstance(exc, KeyboardInterrupt):
                reason = INTERRUPTED
            outcome = "interrupted" if reason == INTERRUPTED else "fault"
            self._close_record(manifest, outcome, reason, steps=0)
            raise
        outcome, reason = "completed", ""
        try:
            self.attach(session)
            self._wait_for_endpoints()
            self._describe_all()
            self._wait_for_view()
            self.prepare(self.descriptions)
            if self.online is not None:  # subscribed before the culture may send a spike
                self.online.announce(self.link, self.n_steps, self.descriptions["culture"].channel)
            self._announce_run()
            self.record_event("start", mode=cfg.loop.mode, n_steps=cfg.n_steps)
            self._steps()
            if self.stop_reason:
                outcome, reason = self._stopped_outcome(), self.stop_reason
        except StoppedBeforeSteps:
            outcome, reason = self._stopped_outcome(), self.stop_reason
            log.info("%s before the first step", reason)
        except (HubError, ConfigError, SchemeError) as exc:
            outcome, reason = "fault", str(exc)
            log.error("%s", exc)
            self.record_event("fault", reason=reason)
        except RecordError as exc:  # a full disk, the run folder gone: a run not recorded stops
            outcome, reason = "fault", str(exc)
            log.error("%s", exc)
            self.recorder.abandon()
            self.recorder = None
        except KeyboardInterrupt:
            outcome, reason = "interrupted", "KeyboardInterrupt"
            raise
        except BaseException as exc:
            outcome, reason = "fault", f"hub crashed: {exc!r}"
            raise
        finally:
            # whatever fails in the close-up, the session closes (its callback threads would
            # keep the process from ever exiting) and the burst observer is stopped
            try:
                self._safe_stop_body()
                endpoint_stats = self._final_counters()  # those alive, whatever the outcome
                self._end_run(outcome)
                if self.online is not None:
                    self.online.end(
                        self.k_done, there=OBSERVER in self.alive, take_waiting=self._take_reports
                    )
                self._publish_view(time.monotonic(), last=True)  # the last steps, for displays
                self.state = "stopped"
                self.ended = (outcome, reason)  # said in the final status, for observers
                self._publish_status()
                timing, counts = self.timing(), self.counts()
                unrecorded = self._close_record(
                    manifest,
                    outcome,
                    reason,
                    steps=self.k_done,
                    timing=timing,
                    counts=counts,
                    rejoins=self.rejoins,
                    endpoints={
                        r: {
                            "kind": d.kind,
                            "id": d.id,
                            **self.participants.get(r, {}),
                            **steps_share(d, endpoint_stats),
                        }
                        for r, d in self.descriptions.items()
                    },
                )
                if unrecorded and outcome != "fault":  # the record is not whole: a fault
                    outcome, reason = "fault", unrecorded
                if self.link is not None and self.link.view_observed():
                    self.link.views.wait_had(LAST_VIEW_WAIT_S)  # a live display's last view
            finally:
                session.close()
                self._release(observer)
        return RunResult(
            outcome, reason, self.k_done, timing, counts, self.run_dir, self.descriptions
        )

    def _close_record(self, manifest: dict, outcome: str, reason: str, **results) -> str:
        """The run's end in its record and its manifest, whatever ended it; what could not be
        written (a full disk, the run folder gone), said in the log, or ``""``."""
        failed = []
        if self.recorder:
            try:
                self.record_event("end", outcome=outcome, reason=reason)
                self.recorder.close()
            except RecordError as exc:
                failed.append(str(exc))
        if self.run_dir:
            manifest.update(end_utc=utc_now(), outcome=outcome, reason=reason, **results)
            try:
                write_manifest(self.run_dir, manifest)
            except OSError as exc:
                failed.append(f"its manifest could not be written to {self.run_dir}: {exc}")
        if not failed:
            return ""
        why = "the run's record could not be closed: " + "; ".join(failed)
        log.error("%s", why)
        return why

    def _release(self, observer: LocalProcess | None) -> None:
        """The CPUs as they were before the run, and the burst observer it started stopped."""
        restore_placement(self.placement)
        if observer is not None:
            stop_local_endpoints([observer])

    # ================================================================ the loop

    def _steps(self) -> None:
        """Run the steps (ARCHITECTURE.md, "The loop") in the configured mode."""
        self.state = "running"
        # Everything allocated during set-up is long-lived: keep it out of the cyclic
        # collector, whose full passes would otherwise stall realtime steps.
        gc.collect()
        gc.freeze()
        switch_s = sys.getswitchinterval()
        sys.setswitchinterval(GIL_SWITCH_S)
        self.cpus_awake = hold_cpus_awake(self.cfg.loop.keep_cpus_awake)
        if not self.cpus_awake.held and self.cfg.loop.keep_cpus_awake:
            log.info("idle CPUs may sleep during the steps: %s", self.cpus_awake.reason)
        try:
            if self.cfg.loop.mode == "lockstep":
                self.times.start()
                self.scheduler.run()
            else:
                self.scheduling = raise_threads(self.cfg.loop.realtime_priority)
                if self.scheduling.policy != "fifo" and self.cfg.loop.realtime_priority:
                    log.warning(
                        "realtime steps under the ordinary scheduler: %s", self.scheduling.reason
                    )
                self.record_event("scheduling", **self.scheduling.to_dict())
                # The schedule starts now: the set-up above is not step 0's lateness.
                self.times.start()
                try:
                    self.scheduler.run()
                finally:
                    restore_threads(self.scheduling)
        finally:
            realtime = self.cfg.loop.mode == "realtime"
            self.times.stop(self.scheduler.start_of(self.k_done) if realtime else 0.0)
            self.cpus_awake.release()
            sys.setswitchinterval(switch_s)

    def next_event(self, until: float) -> bool:
        """Handle one event, waiting at most until ``until``; False if none came."""
        item = self.wait_event(until)
        if item is None:
            self.tick()
            return False
        self.handle(item)
        return True

    def wait_event(self, until: float) -> tuple | None:
        """The next event, waiting at most until ``until``, the next status, or a flush
        of the record is due."""
        now = time.monotonic()
        timeout = min(until - now, self._next_status - now, self.cfg.record.flush_s)
        if self.cfg.loop.mode == "lockstep":  # realtime: views go after steps (_publish_view)
            timeout = min(timeout, self._view_due_at() - now)
        t0 = time.perf_counter()
        try:
            return self.inbox.get(timeout=max(timeout, 0.0))
        except queue.Empty:
            return None
        finally:
            self.times.waiting_s += time.perf_counter() - t0
            self._note_wake()

    def _note_wake(self) -> None:
        """Keep the last gap in the loop's own running longer than its longest wait
        (``record.flush_s``) and a quarter lease: less than a lease lapsing takes."""
        now = time.monotonic()
        gap_s = now - self._last_wake
        self._last_wake = now
        if gap_s > self.cfg.record.flush_s + self.cfg.bus.lease_ms / 4e3:
            self._stall = (now, gap_s)

    def _hub_stalled_s(self) -> float:
        """How long the hub's loop did not run, if that ended within the last few leases
        (an endpoint's death seen then is the hub's doing); 0.0 otherwise."""
        ended, gap_s = self._stall
        return gap_s if time.monotonic() - ended < 5 * self.cfg.bus.lease_ms / 1e3 else 0.0

    def has_event(self) -> bool:
        return not self.inbox.empty()

    def drain(self) -> None:
        while True:
            try:
                item = self.inbox.get_nowait()
            except queue.Empty:
                return
            self.handle(item)

    def tick(self) -> None:
        online = self.online
        if online is not None and online.pending and not self.scheduler.direct:
            if time.monotonic() - online.forwarded_at >= online.forward_s:
                online.forward()
        if self.gone:
            self._check_rejoin_deadlines()
        now = time.monotonic()
        if now >= self._next_status:
            self._next_status = now + 1.0 / self.cfg.loop.status_hz
            self._publish_status()
            if self.progress:
                self.progress(self._progress())
        if now >= self._view_due_at():
            self._publish_view(now)
        if self.recorder:
            self.recorder.tick()

    def _view_due_at(self) -> float:
        """When this (the loop's) thread sends the next view: while lockstep replies are
        taken in their own thread, only once the steps stand still (:meth:`offer_view`)."""
        return self._next_view + (VIEW_STALL_S if self.scheduler.direct else 0.0)

    def offer_view(self, now: float) -> None:
        """Publish a view for live displays if one is due (lockstep: called after a step
        by the reply thread, under the loop's lock)."""
        if now >= self._next_view:
            self._publish_view(now)

    # ================================================================ events

    def handle(self, item: tuple) -> None:
        kind = item[0]
        if kind == "rx":
            self._on_reply(*item[1:])
        elif kind == "refused":
            self._on_refused(*item[1:])
        elif kind == "alive":
            self._on_liveliness(*item[1:])
        elif kind == "control":
            self._on_control(item[1])
        elif kind == "status":  # an observer asks for the run's status (read-only)
            item[1].reply(item[1].key_expr, self.status().encode())
            item[1].drop()
        elif kind == "report":
            self._on_report(item[1])
        elif kind == "report_refused":  # not sealed by the observer of this run
            self.ledger.drop("observer", item[1], item[2])
        elif kind == "stop":
            self.stop_reason = self.stop_reason or item[1]
        # "wake": nothing to do but look at the state

    def _on_report(self, raw: bytes) -> None:
        """A burst observer's report (unsealed already): counted, its bursts recorded."""
        try:
            report = BurstReport.decode(raw)
        except ProtocolError as exc:
            self.ledger.drop("observer", exc.kind, str(exc))
            return
        if self.online is not None:
            self.online.take_report(report)

    def _on_refused(self, role: str, raw: bytes, kind: str, detail: str, t_wall_ns: int) -> None:
        """A payload on a reply key that did not unseal or reassemble: not the endpoint's."""
        self.ledger.drop(role, kind, detail)
        if self.recorder and raw:
            self.recorder.message("drop", self.output_key[role], raw, t_wall_ns)

    def _on_reply(self, role: str, raw: bytes, t_wall_ns: int, t_arrival: float) -> None:
        """Accept, count as late, or drop one reply; record it with that verdict."""
        verdict, message = self._classify_reply(role, raw, t_arrival)
        if self.recorder:
            self.recorder.message(verdict, self.output_key[role], raw, t_wall_ns)
        if role == "culture" and self.online is not None and verdict in ("rx", "late"):
            if verdict == "late" and message.partial:
                return  # a part of a step stood in for: the observer counts that step missing
            # the observer takes a step's spikes at once: with the parts streamed before;
            # a late step's too, as the record keeps them
            online = self.online
            taken = self.ledger.pending[role].get(message.step, message)
            online.pending.append(raw if taken is message else taken.encode())
            if self.scheduler.direct and t_arrival - online.forwarded_at >= online.forward_s:
                online.forward()  # lockstep; realtime: after the step (tick)

    def _note_round_trip(self, role: str, step: int, t_arrival: float) -> None:
        """The time from the input of ``step`` to ``role`` going out to its reply coming in."""
        if 0 <= step < self.n_steps:
            put_at = self._put_at[role][step]
            if put_at == put_at:  # not NaN: the input went out
                rtt_s = t_arrival - put_at
                self.times.round_trip_s[role][step] = rtt_s
                self._last_round_trip_ms[role] = rtt_s * 1e3

    def _classify_reply(self, role: str, raw: bytes, t_arrival: float):
        """The record's verdict on one reply, and the reply (None if dropped)."""
        try:
            message = self.checker.check(role, raw)
        except ProtocolError as exc:
            return self.ledger.drop(role, exc.kind, str(exc)), None
        running = self.state != "waiting"
        if role == "culture" and message.partial:
            verdict = self.ledger.judge_part(role, message, running=running)
            if verdict == "late":  # of a step stood in for: shown as a late reply is
                self.view.took(message)
            return verdict, message
        verdict = self.ledger.judge(role, message, t_arrival, running=running)
        if verdict in ("rx", "late"):
            self._note_round_trip(role, message.step, t_arrival)
            if self.view.observed:
                # live displays get a step's spikes whole (its parts merged): a display
                # closes its rate bins up to the window's end when it gets them
                self.view.took(self.ledger.pending[role].get(message.step, message))
        return verdict, message

    def _on_liveliness(self, key: str, present: bool) -> None:
        parsed = self.keys.parse_alive(key)
        if parsed is None:
            return
        was = parsed in self.alive
        (self.alive.add if present else self.alive.discard)(parsed)
        if was == present:
            return
        self.record_event("alive" if present else "dead", role=parsed[0], id=parsed[1])
        if parsed == OBSERVER and self.online is not None:
            if self.state in ("running", "paused"):
                entry = self.online.came_or_went(present)
                if entry is not None:
                    self.rejoins.append(entry)
            return
        required = parsed[0] in ROLES and self.ids[parsed[0]] == parsed[1]
        if present and required and parsed[0] in self.gone:
            return self._rejoin(parsed[0])
        if not present and required and self.state in ("running", "paused"):
            stalled_s = self._hub_stalled_s()
            if stalled_s:
                raise HubError(
                    f"the hub itself stopped running for {stalled_s:.1f} s (frozen or starved "
                    f"of CPU) at step {self.k}: {parsed[0]}/{parsed[1]}'s lease lapsed meanwhile"
                )
            if self.cfg.policy.rejoin_s > 0:
                log.warning(
                    "%s/%s vanished at step %d: it may rejoin within %g s (policy.rejoin_s)",
                    *parsed, self.k, self.cfg.policy.rejoin_s,
                )  # fmt: skip
                self.gone[parsed[0]] = (time.monotonic(), self.k)
                return
            self._endpoint_dead(*parsed)

    def _endpoint_dead(self, role: str, id: str) -> None:
        """An endpoint is gone for good: ``policy.endpoint_death`` applies."""
        if self.cfg.policy.endpoint_death == "stop":
            raise EndpointDied(role, id, self.k)  # logged once, where the run ends
        log.error(
            "%s/%s died at step %d; the run goes on (policy.endpoint_death = %r)",
            role, id, self.k, self.cfg.policy.endpoint_death,
        )  # fmt: skip

    def _rejoin(self, role: str) -> None:
        """An endpoint that vanished is back within ``policy.rejoin_s``: describe it and give
        it the run again (same id and key; it starts from its model's or device's start).
        Lockstep: the input it owes a reply to is sent again; the loop waited for it."""
        since, gone_at = self.gone.pop(role)
        i = self.ids[role]
        self._describe(role, i)
        self._announce(role, i)
        gap_s = time.monotonic() - since
        entry = {"role": role, "id": i, "gone_at_step": gone_at, "at_step": self.k}
        entry["gap_s"] = round(gap_s, 3)
        self.rejoins.append(entry)
        self.record_event("rejoined", **entry)
        log.warning("%s/%s rejoined at step %d after %.2f s", role, i, self.k, gap_s)
        self.scheduler.rejoined(role)

    def resend_unanswered(self, role: str) -> None:
        """Send ``role`` again the inputs it has not answered (in lockstep up to two are in
        flight), to an endpoint that rejoined."""
        for step in sorted(self.unanswered[role]):
            if step >= self.ledger.expect[role]:
                self._put_at[role][step] = time.monotonic()
                self.link.send(role, self.unanswered[role][step])

    def _check_rejoin_deadlines(self) -> None:
        """An endpoint gone longer than ``policy.rejoin_s`` is dead."""
        now = time.monotonic()
        for role, (since, _) in list(self.gone.items()):
            if now - since > self.cfg.policy.rejoin_s:
                del self.gone[role]
                self.record_event("rejoin_expired", role=role, id=self.ids[role])
                self._endpoint_dead(role, self.ids[role])

    def _on_control(self, query) -> None:
        try:
            request = ControlRequest.decode(payload_bytes(query))
        except ProtocolError as exc:
            self.ledger.drop("control", exc.kind, str(exc))
            return self._reply(query, ControlReply(ok=False, state=self.state, reason=str(exc)))
        self.record_event("control", cmd=request.cmd)
        ok, reason, data = True, "", None
        if request.cmd == "pause":
            ok = self.state == "running"
            if ok:
                self.state = "paused"
                self.times.pause()
                self._hold(True)
        elif request.cmd == "resume":
            ok = self.state == "paused"
            if ok:
                self._hold(False)
                self.times.resume()
                self.state = "running"
        elif request.cmd == "stop":
            self.stop_reason = self.stop_reason or STOPPED_BY_CONTROL
        elif request.cmd == "config":
            data = self.cfg.to_dict()
        data = data if data is not None else self.status().to_dict()
        if not ok:
            reason = f"cannot {request.cmd} while {self.state}"
        # The state the command leads to, as pause and resume reply: a stop takes effect
        # after the current step.
        state = "stopping" if request.cmd == "stop" else self.state
        self._reply(query, ControlReply(ok=ok, state=state, reason=reason, data=data))

    def _hold(self, hold: bool) -> None:
        """Tell each endpoint the run is paused (it makes itself safe at once: the wheels
        stop, nothing is delivered) or resumed; record who acknowledged."""
        taken = self.roster.hold(list(self.ids.items()), self.run_id, hold)
        self.record_event("hold" if hold else "unhold", **taken)
        if not all(taken.values()):
            log.warning("not every endpoint acknowledged the %s: %s",
                        "pause" if hold else "resume", taken)  # fmt: skip

    def _reply(self, query, reply: ControlReply) -> None:
        query.reply(query.key_expr, reply.encode())
        query.drop()

    # ================================================================ set-up

    def attach(self, session: zenoh.Session) -> None:
        """Declare the run on ``session``: the inputs' publishers, the replies' subscription,
        liveliness, control and status (:class:`~hub.link.HubLink`). :meth:`run` does this
        first; a tool or test that drives a scheduler without endpoints does it itself."""
        self.link = HubLink(session, self.keys, self.ids, self.run_keys, self._deliver)
        self.roster = Roster(self.cfg, self.link, self.recorder)

    def _deliver(self, item: tuple) -> None:
        """An event from the bus: replies taken at once in lockstep steps, the rest queued
        for the loop's thread."""
        if self.scheduler.direct and item[0] in ("rx", "refused"):
            self.scheduler.on_reply(item)
        else:
            self.inbox.put(item)

    def _wait_for_endpoints(self) -> None:
        """Wait until every endpoint (and the burst observer, with online analysis) is on
        the bus."""
        needed = {(role, i) for role, i in self.ids.items()}
        if self.online is not None:
            needed.add(OBSERVER)
        start = time.monotonic()
        deadline = start + self.cfg.loop.wait_timeout_s
        next_note = start
        while not needed <= self.alive:
            if time.monotonic() >= next_note:  # say at once what is awaited, then every 5 s
                waiting = ", ".join(f"{r}/{i}" for r, i in sorted(needed - self.alive))
                log.info(
                    "waiting for %s on session %r (%.0f s of %g s): each builds its model "
                    "before it appears; a simulator's first run also compiles its kernels%s",
                    waiting, self.cfg.bus.session, time.monotonic() - start,
                    self.cfg.loop.wait_timeout_s, self.roster.elsewhere(needed - self.alive),
                )  # fmt: skip
                next_note += 5.0
            if self.stop_reason:
                self._stop_while_waiting("endpoints")
            if OBSERVER in needed - self.alive:  # one that ended will not come: say so now
                exited = self.online.exited_early()
                if exited is not None:
                    raise exited
            if time.monotonic() >= deadline:
                missing = ", ".join(f"{r}/{i}" for r, i in sorted(needed - self.alive))
                hint = ""
                if OBSERVER in needed - self.alive:
                    hint = (
                        '; with online.launch = "external" start it with \'neuvision observe '
                        'bursts CONFIG --connect HOST\' ("local": the hub starts it, see '
                        "observer.log in the run folder); online.enabled = false runs "
                        "without live burst detection"
                    )
                raise HubError(
                    f"endpoint(s) {missing} did not appear on session {self.cfg.bus.session!r} "
                    f"within {self.cfg.loop.wait_timeout_s} s (listening on "
                    f"{', '.join(self.cfg.bus.listen)}){hint}"
                    f"{self.roster.elsewhere(needed - self.alive)}"
                )
            self.next_event(min(deadline, time.monotonic() + 0.1))

    def _wait_for_view(self) -> None:
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
            if self.stop_reason:
                self._stop_while_waiting("the dashboard")
            if time.monotonic() >= deadline:
                log.warning(
                    "the dashboard did not watch within %g s: the run starts without it",
                    self.wait_for_view_s,
                )
                self.record_event("view_wait", watched=False, waited_s=self.wait_for_view_s)
                return
            self.next_event(min(deadline, time.monotonic() + 0.05))
        self.record_event("view_wait", watched=True, waited_s=time.monotonic() - start)
        self.view.watch(True)  # gather from the first step

    def _stop_while_waiting(self, what: str) -> None:
        """A stop while waiting: the user's (a signal, ``ctl stop``) ends the run as it
        would during the steps; any other (a local endpoint exited) is a fault."""
        if self.stop_reason in (INTERRUPTED, STOPPED_BY_CONTROL):
            raise StoppedBeforeSteps(self.stop_reason)
        raise HubError(f"stopped while waiting for {what} ({self.stop_reason})")

    def _stopped_outcome(self) -> str:
        return "interrupted" if self.stop_reason == INTERRUPTED else "stopped"

    def _describe_all(self) -> None:
        for role, i in self.ids.items():
            self._describe(role, i)

    def _describe(self, role: str, i: str) -> None:
        """Ask one endpoint to describe itself; keep what its replies are checked against."""
        desc, where = self.roster.describe(role, i)
        self.participants[role] = where
        self._take_description(desc)
        self.record_event("described", role=role, id=i, kind=desc.kind)

    def _announce_run(self) -> None:
        """Give each endpoint the run: its id, timing and that endpoint's key (contract v2)."""
        for role, i in self.ids.items():
            self._announce(role, i)

    def _announce(self, role: str, i: str) -> None:
        """Give one endpoint the run (again, when it rejoins: the same id, timing and key)."""
        cfg = self.cfg
        if self._start_unix_s is None:
            self._start_unix_s = time.time()
        start = RunStart(
            run=self.run_id,
            period_ms=float(cfg.loop.period_ms),
            n_steps=cfg.n_steps,
            mode=cfg.loop.mode,
            start_unix_s=self._start_unix_s,
            deadline_ms=cfg.loop.deadline_s * 1e3,
            key=self.run_keys[role],
            seed=cfg.experiment.seed,
        )
        self.roster.announce(role, i, start)
        self.record_event("run_taken", role=role, id=i, run=self.run_id)

    def _take_reports(self) -> None:
        """After the steps: handle the burst observer's reports waiting; nothing else
        waiting matters to the run any more (an endpoint's end, a late reply)."""
        while True:
            try:
                item = self.inbox.get_nowait()
            except queue.Empty:
                return
            if item[0] in ("report", "report_refused"):
                self.handle(item)

    def _final_counters(self) -> dict[str, dict]:
        """Each endpoint's own counters at the end (drops, steps, busy time), if it answers."""
        return self.roster.final_counters(
            [(r, i) for r, i in self.ids.items() if (r, i) in self.alive]
        )

    def _end_run(self, outcome: str) -> None:
        """Tell each endpoint still there that the run is over (it makes itself safe)."""
        there = [(r, i) for r, i in self.ids.items() if (r, i) in self.alive]
        self.roster.end([(r, i) for r, i in there if r in self.descriptions], self.run_id, outcome)

    def _take_description(self, desc: Description) -> None:
        """Keep an endpoint's description, and what its replies are checked against (one
        that cannot take this run's loop is a fault before the run is announced)."""
        warning = check_fits_loop(desc, self.cfg.loop)
        if warning:
            log.warning("%s", warning)
            self.record_event("warning", role=desc.role, id=desc.id, reason=warning)
        self.descriptions[desc.role] = desc
        self.checker.take_description(desc)

    def prepare(self, descriptions: dict[str, Description]) -> None:
        """Take the endpoints' descriptions and build what the loop needs of them: the input
        policy (coding, decoding, limits) and the live burst detector. :meth:`run` does this
        once every endpoint has described itself.

        Raises
        ------
        SchemeError, ConfigError
            A scheme does not fit the endpoints, or the online analysis's settings are bad.
        """
        self.descriptions = dict(descriptions)
        self._build_schemes()

    def _build_schemes(self) -> None:
        cfg = self.cfg
        try:
            self.inputs = InputPolicy(
                cfg,
                self.descriptions["body"],
                self.descriptions["culture"],
                self.run_id,
                on_refused=lambda scheme, why: self.ledger.drop(scheme, "limit", why),
            )
        except ConfigError as exc:  # the params were checked before; this needs the endpoints
            raise ConfigError(
                f"the schemes do not fit the endpoints' descriptions: {exc}"
            ) from None
        if cfg.online.enabled:
            for name, kind in (("burst", BurstParams), ("network", NetworkBurstParams)):
                try:
                    kind(**getattr(cfg.online, name))
                except (TypeError, ValueError) as exc:
                    raise ConfigError(f"online.{name}: {exc}") from None

    # ================================================================ output

    def send(self, role: str, message: Message, raw: bytes | None = None) -> None:
        raw = raw or message.encode()
        # Stamped before the put: a reply can come (and be stamped) before the put returns.
        t_wall_ns = time.time_ns() if self.recorder else None
        put_at = time.monotonic()
        self.link.send(role, raw)
        self.ledger.sent(role, message.step)
        if 0 <= message.step < self.n_steps:
            self._put_at[role][message.step] = put_at
        if self._keep_unanswered:
            unanswered = self.unanswered[role]
            for step in [k for k in unanswered if k < self.ledger.expect[role]]:
                del unanswered[step]
            unanswered[message.step] = raw
        if self.view.observed:
            self.view.sent(message)
        if self.recorder:
            self.recorder.message("tx", self.input_key[role], raw, t_wall_ns)

    def _safe_stop_body(self) -> None:
        """Whatever ended the run, leave the robot stopped, and wait a little for the
        body's reply to the stop: the proof that it was applied (recorded either way)."""
        # Sent whether or not the body looks alive: a frozen body gets it if it comes back
        # in time (it also stops itself: its input timeout, the hub's liveliness).
        if self.link is None or not self.descriptions.get("body"):
            return
        step = self.ledger.final_step = self.ledger.last_sent.get("body", -1) + 1
        self.send("body", MotorCommand.stop(self._window(step)))
        if self.state == "waiting":  # the run was never announced: nothing will answer
            return
        t0 = time.monotonic()
        until = t0 + self.cfg.loop.final_stop_wait_s
        try:
            while step not in self.ledger.pending["body"] and time.monotonic() < until:
                self.next_event(until)
        except HubError:  # the body died meanwhile: it stops itself (input timeout, lease)
            pass
        seen = step in self.ledger.pending["body"]
        self.record_event(
            "final_stop", step=step, acknowledged=seen, wait_s=round(time.monotonic() - t0, 4)
        )
        if not seen:
            log.warning(
                "the body did not answer the final stop within %.2f s (loop.final_stop_wait_s);"
                " it stops itself on its own input timeout",
                self.cfg.loop.final_stop_wait_s,
            )

    def _window(self, k: int) -> StepWindow:
        return StepWindow.of(self.run_id, k, self.period_s)

    def record_event(self, name: str, **details) -> None:
        """Record something the hub noticed or did (an ``ev`` frame; none without a record)."""
        if self.recorder:
            self.recorder.event(name, **details)

    def status(self) -> HubStatus:
        wall, running = self.times.wall_s(), self.times.running_s()
        done = self.k_done
        tally = self.online.tally if self.online else None
        return HubStatus(
            step=self.k,
            t_s=done * self.cfg.loop.period_ms / 1e3,
            mode=self.cfg.loop.mode,
            state=self.state,
            late=dict(self.ledger.late),
            missing={r: len(s) for r, s in self.ledger.missed.items() if s},
            dropped={r: sum(c.values()) for r, c in self.ledger.dropped.items()},
            alive=sorted(f"{r}/{i}" for r, i in self.alive),
            wall_s=wall,
            steps_per_s=done / running if running > 0 else 0.0,
            extra={
                "late_steps": self.times.late_steps,
                "single_channel_bursts": tally.bursts if tally else 0,
                "network_bursts": tally.network_bursts if tally else 0,
                "network_burst_under_way_ms": tally.onset_ms if tally else None,
                # [onset_ms, last seen under way (ms)] each, the latest 8
                "recent_network_bursts_under_way": [
                    [round(v, 3) for v in u] for u in (tally.under_way if tally else ())
                ],
                "round_trip_ms": dict(self._last_round_trip_ms),
                # a stop asked for (or decided) takes effect after the current step
                "stop_reason": self.stop_reason or "",
                # for observers (the dashboard, docs/dashboard.md)
                "run": self.run_id,
                "period_ms": float(self.cfg.loop.period_ms),
                "n_steps": self.cfg.n_steps,
                # [start_ms, end_ms, n_channels, core_start_ms, core_end_ms] each
                "recent_network_bursts": [
                    [round(v, 3) for v in nb] for nb in (tally.recent if tally else ())
                ],
                **self.times.lateness_now(done),
                # how the run ended: in the final status (state "stopped")
                **({"outcome": self.ended[0], "reason": self.ended[1]} if self.ended else {}),
            },
        )

    def _publish_view(self, now: float, *, last: bool = False) -> None:
        """A view for live displays, if anyone asks for them and the loop moved (hub/view.py);
        whether anyone asks is looked at four times a second meanwhile. In realtime
        steps, only in the slack before the next step (``last``: the run's last view)."""
        hz = self.cfg.loop.view_hz
        if self.link is None or not hz:
            self._next_view = math.inf
            self.ledger.stranded.clear()
            return
        if not last and self.state == "running" and self.cfg.loop.mode == "realtime":
            if self.scheduler.start_of(self.k_done) - now < VIEW_GUARD_S:
                return  # the tick after this step tries again
        self.view.watch(self.link.view_observed())
        for part in self.ledger.stranded:  # of steps that went missing: shown as late
            self.view.took(part)
        self.ledger.stranded.clear()
        self._next_view = now + (1.0 / hz if self.view.observed else LOOK_S)
        view = self.view.build(self.k_done)
        if view is not None:
            self.link.publish_view(view.encode())

    def _publish_status(self) -> None:
        if self.link is not None:
            self.link.publish_status(self.status().encode())

    def _progress(self) -> Progress:
        s = self.status()
        return Progress(
            s.step, self.cfg.n_steps, s.t_s, s.wall_s, s.steps_per_s, self.times.late_steps, s.state
        )

    # ================================================================ summaries

    def timing(self) -> dict:
        """Loop timing figures of the run so far (wall time, lateness, late steps)."""
        return self.times.report(self.k_done, self.scheduling, self.cpus_awake)

    def counts(self) -> dict:
        """Online bursts, late, missing and dropped messages so far."""
        ledger = self.ledger
        tally = self.online.tally if self.online else None
        return counts(tally, ledger.late, ledger.missed, ledger.dropped)
