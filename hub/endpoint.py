"""The endpoint base class: what every participant of the loop does on the bus.

A subclass supplies the model or the device: :meth:`Endpoint.describe` and
:meth:`Endpoint.step`, plus for a device :meth:`Endpoint.start_run`,
:meth:`Endpoint.make_safe` and :meth:`Endpoint.close`. :meth:`Endpoint.serve` does the
rest (contract v2, docs/contract.md):

- declares the ``describe`` and ``run`` queryables and then its liveliness token;
- takes a run when the hub announces it (``RunStart``: run id, period, number of steps,
  the key this endpoint and the hub seal their messages with), refuses another run while
  one is going, makes itself safe when the run is paused (``RunHold``), and ends it on
  ``RunEnd`` or when the hub's liveliness vanishes;
- receives each step's input, unseals and validates it, checks it against the run (step
  order, window) and against the endpoint's own limits, calls ``step`` with the input's
  window, and publishes the sealed output;
- drops and counts whatever fails (``foreign``, ``stale``, ``future``, ``window``,
  ``limit`` and the schema's kinds): it is never stepped on;
- makes the device safe when no input came for ``input_timeout_s``, when the run ends,
  and when the hub goes away — none of which needs the hub to be alive;
- shuts down cleanly on SIGINT/SIGTERM, always closing the Zenoh session.
"""

from __future__ import annotations

import abc
import dataclasses
import gc
import logging
import math
import signal
import threading
import time
from collections import Counter
from collections.abc import Sequence

import zenoh

from hub import protocol, stopping, wire
from hub.bus import (
    HUB_CHECK_S,
    LOOP_PUBLISH,
    TELEMETRY_PUBLISH,
    UNSERVED,
    HubWatch,
    hub_answers,
    open_session,
    payload_bytes,
    reaches_anyone,
)
from hub.config import BusSection, ConfigError, EndpointSection, ExperimentConfig
from hub.limits import StimulationLimits, motor_violation
from hub.protocol import (
    INPUT_TYPE,
    OUTPUT_TYPE,
    WINDOW_TOLERANCE_S,
    Description,
    Keys,
    Message,
    ProtocolError,
    RunEnd,
    RunHold,
    RunReply,
    RunStart,
    StepWindow,
    decode_run_request,
)
from hub.scheduling import (
    CpusAwake,
    Scheduling,
    available_cpus,
    hold_cpus_awake,
    place_threads,
    raise_threads,
    restore_placement,
    restore_threads,
)
from hub.stopping import StopFlag

log = logging.getLogger(__name__)


def _host() -> dict:
    import os
    import platform
    import socket
    from importlib.metadata import PackageNotFoundError, version

    def installed(package: str) -> str:
        try:
            return version(package)
        except PackageNotFoundError:
            return "absent"

    return {
        "hostname": socket.gethostname(),
        "pid": os.getpid(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "neuvision": installed("neuvision"),
        "eclipse-zenoh": installed("eclipse-zenoh"),
    }


_HOST = _host()


class _StoppedWaiting(Exception):
    """Asked to stop while still waiting for the hub."""


class DeviceFault(Exception):
    """A device endpoint's device failed (a serial link silent, a port gone): named, and
    the endpoint's process ends with it (``neuvision endpoint``: one line, exit status 2)."""


class RunRefused(Exception):
    """Raised by :meth:`Endpoint.start_run`: this endpoint cannot serve that run (why)."""


class Endpoint(abc.ABC):
    """A body or culture served on the bus.

    Parameters
    ----------
    id : str
        Which body or culture this is (``nv/<s>/<role>/<id>/...``).
    input_timeout_s : float
        With no input for this long, :meth:`on_input_timeout` is called once per
        silence (by default :meth:`make_safe`: a body stops its motors).
    """

    role: str = ""  # "body" or "culture", set by subclasses
    kind: str = ""  # e.g. "sim_robot", "sim_network", "khepera"
    # hub.launch.settings_digest (and settings_digests: each setting's) of the experiment it
    # was built from (set by `neuvision endpoint`), in its description's counters; None: not
    # known, not compared
    settings_digest: str | None = None
    settings_digests: dict[str, str] | None = None

    def __init__(self, id: str = "0", *, input_timeout_s: float = 1.0):
        if self.role not in INPUT_TYPE:
            raise TypeError(f"{type(self).__name__}.role must be 'body' or 'culture'")
        self.id = str(id)
        self.input_timeout_s = input_timeout_s
        self.dropped: Counter[str] = Counter()
        self.busy_s = 0.0  # time spent in step(): the model's or device's share of a run
        self.steps = 0
        self.last_step = -1
        self.run: RunStart | None = None  # the run being served (None: idle)
        self.runs = 0  # runs taken since serving began
        self.holds = 0  # pauses of the hub (each made the device safe)
        self.keys = Keys()
        self.scheduling = Scheduling("normal", reason="not serving")
        self.cpus_awake = CpusAwake(False, reason="no run served yet")
        self._keep_cpus_awake = False  # serve(keep_cpus_awake=...): held while a run is served
        self._inbox = wire.Inbox()
        self._outbox: wire.Outbox | None = None
        self._owed: set[int] = set()  # steps stepped on whose reply has not left yet
        self._limits: StimulationLimits | None = None
        self._described: Description | None = None
        self._lock = threading.RLock()  # one of input, reply, run change, timeout at a time
        self._stop = StopFlag()  # set by signal handlers too
        self._session = None
        self._telemetry: dict = {}
        self._once = False  # serve(once=True): stop when the first run ends
        self._run_lost = False  # a run ended by its hub's going, not by the hub (RunEnd)
        self._ended_run = ""  # the id of the run that ended last
        self._run_taken_at = -math.inf  # when the current run was taken (monotonic)
        protocol.kernels()  # the checks of larger arrays compiled now, not in a run

    # ------------------------------------------------------------ for subclasses

    @classmethod
    def from_config(cls, section: EndpointSection, cfg: ExperimentConfig) -> Endpoint:
        """Build from the experiment's ``[body]``/``[culture]`` section.

        Subclasses read ``section.params`` here, raising
        :class:`~hub.config.ConfigError` that names ``<role>.params.<key>``.

        Parameters
        ----------
        section : EndpointSection
            This endpoint's section (its ``id`` and ``params``).
        cfg : ExperimentConfig
            The whole experiment, for what a subclass needs beyond its section.

        Raises
        ------
        ConfigError
            A parameter this endpoint does not take (by default: any).
        """
        if section.params:
            raise ConfigError(
                f"{cls.role}.params: {cls.__name__} takes no parameters, "
                f"got {sorted(section.params)}"
            )
        return cls(section.id)

    @abc.abstractmethod
    def describe(self) -> Description:
        """What this endpoint is: its kind, geometry (channels or sensors) and limits."""

    @abc.abstractmethod
    def step(self, message: Message, window: StepWindow) -> Message | None:
        """Apply one step's input over ``window`` and return the output for it.

        Parameters
        ----------
        message : Message
            A validated :class:`~hub.protocol.MotorCommand` (body) or
            :class:`~hub.protocol.Stimulation` (culture) of the current run.
        window : StepWindow
            Its step and run time ``[t0_s, t1_s)``.

        Returns
        -------
        Message or None
            The :class:`~hub.protocol.SensorReading` or :class:`~hub.protocol.SpikeBatch`
            for that window (same ``step`` and ``run``; a SpikeBatch with the window's
            ``t0_s``/``t1_s``), or None to reply later through :meth:`reply` (a device
            that collects over the window answers when the window has passed).
        """

    def start_run(self, run: RunStart) -> None:
        """A run begins: reset the model or device to its step 0 for ``run``'s period.

        Raise :class:`RunRefused` with the reason if this endpoint cannot serve it (a
        period it cannot step, a device not ready). Default: nothing to reset.
        """

    def end_run(self) -> None:
        """The run is over (``RunEnd``, or the hub went away). Default: :meth:`make_safe`."""
        self.make_safe()

    def make_safe(self) -> None:
        """Leave the device harmless: a body stops its motors, a culture stops stimulating.
        Default: nothing (a simulator has nothing to make safe)."""

    def warm_up(self) -> None:
        """Run what the first step would compile or load, leaving the state as it was
        (called before the endpoint declares itself alive). Default: nothing."""

    def on_input_timeout(self) -> None:
        """No input for ``input_timeout_s``. Default: :meth:`make_safe`."""
        self.make_safe()

    def close(self) -> None:
        """Stop the device and release it. Default: nothing."""

    def publish_telemetry(self, key: str, message: Message) -> None:
        """Publish an observer-only message (newest wins; never blocks the loop).

        Nothing is sent while no session is open.

        Parameters
        ----------
        key : str
            The key expression it goes on (a publisher is declared on first use).
        message : Message
            What to send, encoded here.
        """
        if self._session is None:
            return
        publisher = self._telemetry.get(key)
        if publisher is None:
            publisher = self._session.declare_publisher(key, **TELEMETRY_PUBLISH)
            self._telemetry[key] = publisher
        publisher.put(message.encode())

    # ------------------------------------------------------------ the run

    def description(self) -> Description:
        """:meth:`describe` with this endpoint's counters: drops by kind, steps, runs, busy
        time (inside :meth:`step`) and CPU time of the process so far."""
        counters = {
            "dropped": dict(self.dropped),
            "steps": self.steps,
            "runs": self.runs,
            "holds": self.holds,
            "run": self.run.run if self.run else "",
            "busy_s": self.busy_s,
            "cpu_s": time.process_time(),  # the whole process, every thread
            "scheduling": self.scheduling.to_dict(),
            "cpus_awake": self.cpus_awake.to_dict(),
        }
        cpus = available_cpus()
        if cpus is not None:
            counters["cpus"] = sorted(cpus)  # those this process could run on
        counters["host"] = _HOST  # where it runs: the manifest names every participant
        if self.settings_digest is not None:  # what it serves: the hub compares its own
            counters["settings_digest"] = self.settings_digest
        if self.settings_digests is not None:  # and names the settings that differ
            counters["settings_digests"] = self.settings_digests
        counters["unix_time_s"] = time.time()  # the hub estimates the clock offset
        return dataclasses.replace(self._description(), counters=counters)

    def _description(self) -> Description:
        if self._described is None:
            self._described = self.describe()
        return self._described

    def take_run_request(self, raw: bytes) -> RunReply:
        """Handle a ``RunStart`` or ``RunEnd`` (the payload of a query on the ``run`` key)."""
        try:
            request = decode_run_request(raw)
        except ProtocolError as exc:
            self._drop(exc.kind, f"run request: {exc}")
            return RunReply(ok=False, run="", reason=str(exc))
        with self._lock:
            current = self.run
            if isinstance(request, RunHold):
                if current is None or current.run != request.run:
                    return RunReply(ok=False, run=request.run, reason="not serving that run")
                if request.hold:
                    log.info("%s/%s: run %s paused", self.role, self.id, request.run)
                    self.make_safe()
                else:
                    log.info("%s/%s: run %s resumed", self.role, self.id, request.run)
                self.holds += int(request.hold)
                return RunReply(ok=True, run=request.run)
            if isinstance(request, RunEnd):
                if current is None or current.run != request.run:
                    return RunReply(ok=False, run=request.run, reason="not serving that run")
                # with ``once``, serve() stops after the reply has gone (on_run)
                self._end_run(f"the hub ended it ({request.outcome})", stop=False)
                return RunReply(ok=True, run=request.run)
            if current is not None:
                if current.run == request.run:
                    return RunReply(ok=True, run=request.run)  # the same announcement again
                return RunReply(ok=False, run=request.run, reason=f"busy with run {current.run}")
            try:
                self.start_run(request)
            except RunRefused as exc:
                log.warning("%s/%s refused run %s: %s", self.role, self.id, request.run, exc)
                return RunReply(ok=False, run=request.run, reason=str(exc))
            self.run, self.last_step, self.runs = request, -1, self.runs + 1
            self._owed.clear()
            self._inbox.key = request.key
            if self._outbox is not None:
                self._outbox.key = request.key
            culture = self.role == "culture"
            self._limits = StimulationLimits(self._description()) if culture else None
            self._run_taken_at = time.monotonic()  # the hub's inputs are due from now
            self.cpus_awake = hold_cpus_awake(self._keep_cpus_awake)
            if self._keep_cpus_awake and not self.cpus_awake.held:
                log.info(
                    "%s/%s: idle CPUs may sleep: %s", self.role, self.id, self.cpus_awake.reason
                )
            log.info("%s/%s took run %s", self.role, self.id, request.run)
            return RunReply(ok=True, run=request.run)

    def _end_run(self, why: str, stop: bool = True) -> None:
        """Back to idle; the device made safe (under the lock). With ``once``: stop (unless
        ``stop`` is False: the caller stops once it has answered the hub)."""
        log.info("%s/%s: run %s ended: %s", self.role, self.id, self.run.run, why)
        self._ended_run = self.run.run
        self.run = None
        self._owed.clear()
        self._inbox.key = None
        self.cpus_awake.release()
        self.end_run()
        if self._once and stop:
            self._stop.set()

    def on_hub_gone(self) -> None:
        """The hub's liveliness vanished: the run ends here and now, the device made safe."""
        with self._lock:
            if self.run is not None:
                self._run_lost = True
                self._end_run("the hub went away")

    # ------------------------------------------------------------ each step

    def handle(self, payload) -> Message | None:
        """Unseal, validate and check one input (a put's payload: bytes or ``zenoh.ZBytes``,
        its seal at its end) and step on it.

        Returns the output to publish, or None when the input was dropped (counted) or
        the endpoint replies later (:meth:`reply`).
        """
        with self._lock:
            run = self.run
            if run is None:
                self._drop("foreign", "an input while no run is going")
                return None
            try:
                raw = self._inbox.feed(payload)
            except wire.WireError as exc:
                self._drop(exc.kind, str(exc))
                return None
            if raw is None:  # more frames to come
                return None
            try:
                message = INPUT_TYPE[self.role].decode(raw)
            except ProtocolError as exc:
                self._drop(exc.kind, str(exc))
                return None
            window = self._check_input(message, run)
            if window is None:
                return None
            self.last_step = message.step
            self._owed.add(message.step)
            t0 = time.perf_counter()
            output = self.step(message, window)
            self.busy_s += time.perf_counter() - t0
            self.steps += 1
            if output is None:
                return None
            self._check_output(output)
            self._owed.discard(output.step)
            return output

    def _check_input(self, message: Message, run: RunStart) -> StepWindow | None:
        """The input's window if it may be stepped on; else None (dropped and counted)."""
        step = message.step
        if message.run != run.run:
            return self._drop("foreign", f"an input of run {message.run!r} during {run.run}")
        if step <= self.last_step:
            return self._drop("stale", f"step {step} after step {self.last_step}")
        if step > run.n_steps:  # n_steps itself: the hub's final stop after the last step
            return self._drop("future", f"step {step} beyond the run's {run.n_steps} steps")
        window = run.window(step)
        if (
            abs(message.t0_s - window.t0_s) > WINDOW_TOLERANCE_S
            or abs(message.t1_s - window.t1_s) > WINDOW_TOLERANCE_S
        ):
            return self._drop(
                "window", f"step {step} window [{message.t0_s}, {message.t1_s}) is not the run's"
            )
        if self.role == "body":
            why = motor_violation(message, self._description())
            if why is not None:
                self._drop("limit", f"step {step}: {why}; motors stopped")
                self.make_safe()
                return None
        else:
            why = self._limits.violation(message)
            if why is not None:
                return self._drop("limit", f"step {step}: {why}; nothing delivered")
            self._limits.accept(message)
        return window

    def _check_output(self, output: Message) -> None:
        """A subclass's output must answer a step owed, in this run (a bug otherwise)."""
        kind = OUTPUT_TYPE[self.role]
        run = self.run
        if (
            not isinstance(output, kind)
            or run is None
            or output.run != run.run
            or output.step not in self._owed
        ):
            raise TypeError(
                f"{type(self).__name__} replied {output!r}; expected a {kind.__name__} of run "
                f"{run.run if run else None} for one of steps {sorted(self._owed)}"
            )

    def reply(self, output: Message) -> None:
        """Publish the output of a step answered later (thread-safe). A culture's part of
        a step's spikes (``SpikeBatch(partial=True)``, contract v4) leaves the step owed:
        its batch must follow.

        An output of the run that just ended (its device answered as the run ended: a
        stop, an interrupt) is let go: nobody takes it any more.

        Raises
        ------
        TypeError
            ``output`` is not the output of a step owed in the current run (a bug).
        """
        with self._lock:
            ended = self.run is None or output.run != self.run.run
            if ended and getattr(output, "run", None) == self._ended_run:
                log.debug("%s/%s: step %s answered after its run ended: let go",
                          self.role, self.id, output.step)  # fmt: skip
                return
            self._check_output(output)
            if not getattr(output, "partial", None):
                self._owed.discard(output.step)
            if self._outbox is not None:
                self._outbox.put(output.encode())

    def _drop(self, kind: str, detail: str) -> None:
        if not self.dropped[kind]:
            log.warning("%s/%s dropped a message (%s): %s", self.role, self.id, kind, detail)
        self.dropped[kind] += 1

    # ------------------------------------------------------------ serving

    def _waiting(self, where: str, waited_s: float) -> None:
        if self._stop.is_set():
            raise _StoppedWaiting  # nothing was opened: a clean stop
        log.info(
            "%s/%s: waiting for the hub at %s (%.0f s so far): is it started?",
            self.role, self.id, where, waited_s,
        )  # fmt: skip

    def request_stop(self) -> None:
        """Ask :meth:`serve` to return (thread-safe; used by signal handlers)."""
        self._stop.set()

    def serve(
        self,
        bus: BusSection,
        *,
        install_signals: bool = True,
        realtime_priority: int = 0,
        cpus: Sequence[int] = (),
        keep_cpus_awake: bool = False,
        once: bool = False,
    ) -> int:
        """Serve on the bus until stopped; return the exit status (0 on a clean stop).

        An endpoint serves one run after another (each ``RunStart`` resets it).

        Parameters
        ----------
        bus : BusSection
            Where the hub is and how to reach it.
        install_signals : bool
            Stop on SIGINT/SIGTERM (only from the main thread).
        realtime_priority : int
            > 0: this process's threads go under ``SCHED_FIFO`` at that priority once
            warmed up (see :mod:`hub.scheduling`; refused: ordinary scheduling).
        cpus : sequence of int
            Keep the process's threads on those CPUs (``<role>.cpus``; empty: the OS
            decides).
        keep_cpus_awake : bool
            Ask the OS to keep idle CPUs awake while a run is served
            (``loop.keep_cpus_awake``; :func:`hub.scheduling.hold_cpus_awake`).
        once : bool
            Return when the first run ends: 0 when the hub ended it, whatever the run's
            outcome; :data:`UNSERVED` when the hub went in the middle of it without ending
            it, or when a hub that answered leaves without starting one (it refused this
            endpoint: other settings, a second endpoint of the same name).
        """
        self._once = once
        self._keep_cpus_awake = keep_cpus_awake
        if install_signals:
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, lambda *_: self.request_stop())
            if stopping.signalled_while_starting():  # and its KeyboardInterrupt was lost
                self.request_stop()
        keys = self.keys = Keys(bus.session)
        placement = place_threads(f"{self.role}.cpus", cpus)
        if placement.reason:
            log.warning("%s.cpus not applied: %s", self.role, placement.reason)
        try:
            self._description()  # described once: what inputs are checked against
            self.warm_up()  # so that the first realtime steps are not late
            if self._stop.is_set():  # stopped while it started: nothing opened yet
                raise _StoppedWaiting
            where = ", ".join(bus.connect or bus.listen)
            log.info("%s/%s: connecting to the hub at %s", self.role, self.id, where)
            session = self._session = open_session(
                bus, listener=False, role=self.role, on_wait=self._waiting
            )
        except _StoppedWaiting:
            restore_placement(placement)
            self.close()
            return 0
        except BaseException:
            restore_placement(placement)
            raise
        # Once Zenoh's threads exist: the policy is not inherited by new threads.
        self.scheduling = raise_threads(realtime_priority)
        if realtime_priority and self.scheduling.policy != "fifo":
            log.warning("%s/%s: %s", self.role, self.id, self.scheduling.reason)
        publisher = session.declare_publisher(keys.output(self.role, self.id), **LOOP_PUBLISH)
        self._outbox = wire.Outbox(publisher)
        # Inputs are stepped on in the subscriber's own callback thread (one thread, so in
        # order): handing them to this thread would cost a wake-up per step. This thread
        # only watches for the input timeout and the stop request.
        state = {
            "last_input": time.monotonic(),
            "serving": True,
            "hub_token": False,  # the last news of the hub's token was a PUT
        }
        status = 0
        failures: list[BaseException] = []

        def on_input(sample) -> None:
            with self._lock:
                if not state["serving"]:
                    return
                try:
                    output = self.handle(sample.payload)
                    state["last_input"] = time.monotonic()
                    if output is not None:
                        self._outbox.put(output.encode())
                    if self.steps == 1:  # this callback thread has started now
                        self.scheduling.include_new_threads()
                except BaseException as exc:  # handed to serve(), which re-raises it
                    state["serving"] = False
                    failures.append(exc)
                    self._stop.set()

        def on_describe(query) -> None:
            with self._lock:
                raw = self.description().encode()
            wire.reply(query, raw)

        def on_run(query) -> None:
            wire.reply(query, self.take_run_request(payload_bytes(query)).encode())
            if once and self.runs and self.run is None:  # its run ended, and the hub knows
                self._stop.set()

        def on_hub_alive(sample) -> None:
            state["hub_token"] = sample.kind != zenoh.SampleKind.DELETE
            if sample.kind == zenoh.SampleKind.DELETE:
                self.on_hub_gone()
            elif hub_left is not None:
                hub_left.seen = True

        def hub_there() -> bool:
            """Whether the hub is on the bus: its token answers a liveliness query, or its
            last news was a PUT and the session still reaches someone. A query alone is not
            enough: Zenoh answered one with nothing while another participant joined."""
            if hub_answers(session, keys):
                return True
            return state["hub_token"] and reaches_anyone(session)

        # serving one run: whether a hub that was there left (it refused this endpoint, or
        # ended) or one under another session, never seen, ended: it will not start one
        hub_left = HubWatch(session, keys, there=hub_there) if once else None

        try:
            # Zenoh undeclares what is garbage-collected: keep every declaration.
            declared = [  # noqa: F841
                session.declare_subscriber(keys.input(self.role, self.id), on_input),
                session.declare_queryable(keys.describe(self.role, self.id), on_describe),
                session.declare_queryable(keys.run(self.role, self.id), on_run),
                session.liveliness().declare_subscriber(keys.hub_alive, on_hub_alive, history=True),
            ]
            # Declared last: when the hub sees us alive, we already listen.
            token = session.liveliness().declare_token(keys.alive(self.role, self.id))  # noqa: F841
            gc.collect()
            gc.freeze()  # the model is long-lived: keep full collections short
            log.info("%s/%s (%s) ready on session %s", self.role, self.id, self.kind, bus.session)
            timed_out = False
            next_hub_check, unanswered = 0.0, 0
            while not self._stop.wait(0.05):
                if hub_left is not None and self.runs == 0 and hub_left():
                    log.error(
                        "%s/%s: the hub %s left without starting a run with it (did it "
                        "refuse it, or run under another session than %r? its log says "
                        "why): exiting (--once)",
                        self.role, self.id,
                        "it reached" if hub_left.seen else "or router it reached",
                        bus.session,
                    )  # fmt: skip
                    status = UNSERVED
                    break
                with self._lock:
                    idle_s = time.monotonic() - state["last_input"]
                    if idle_s <= self.input_timeout_s:
                        timed_out = False
                    elif not timed_out:
                        timed_out = True
                        self.on_input_timeout()
                    in_run = self.run is not None
                    # in this run: since its last input, or since it was taken
                    run_idle_s = min(idle_s, time.monotonic() - self._run_taken_at)
                # A run whose inputs stopped: is its hub still there? A hub killed takes its
                # router with it, and its clients hear no liveliness change then (they would
                # stay busy with its run, and refuse the next hub's). Paused, it answers.
                # Two silent checks in a row: one may come as a new router's token does.
                now = time.monotonic()
                if not in_run or run_idle_s <= self.input_timeout_s:
                    unanswered = 0
                elif now >= next_hub_check:
                    next_hub_check = now + HUB_CHECK_S
                    unanswered = 0 if hub_there() else unanswered + 1
                    if unanswered >= 2:
                        unanswered = 0
                        log.warning(
                            "%s/%s: the hub does not answer (no input for %.1f s)",
                            self.role, self.id, run_idle_s,
                        )  # fmt: skip
                        self.on_hub_gone()
        finally:
            try:
                with self._lock:
                    state["serving"] = False
                    self.make_safe()
                    self.close()
            finally:
                self._telemetry.clear()
                self._session = None
                session.close()
                self.cpus_awake.release()
                restore_threads(self.scheduling)
                restore_placement(placement)
        if failures:
            raise failures[0]
        if self.dropped:
            log.info("%s/%s dropped: %s", self.role, self.id, dict(self.dropped))
        if once and self._run_lost:
            log.error(
                "%s/%s: the hub went in the middle of its run without ending it: exiting "
                "(--once) with status %d",
                self.role, self.id, UNSERVED,
            )  # fmt: skip
            status = UNSERVED
        return status
