"""The endpoint base class: what every participant of the loop does on the bus.

A subclass supplies the model or the device: :meth:`Endpoint.describe` and
:meth:`Endpoint.step` (plus, for devices, :meth:`Endpoint.on_input_timeout` and
:meth:`Endpoint.close`). :meth:`Endpoint.serve` does the rest: opens the
session, declares the liveliness token and the ``describe`` queryable, receives
the input of each step, validates it, calls ``step``, publishes the output, and
counts and drops what is malformed, out of order or from the far future. It
shuts down cleanly on SIGINT/SIGTERM, always closing the Zenoh session.
"""

from __future__ import annotations

import abc
import dataclasses
import gc
import logging
import signal
import threading
import time
from collections import Counter
from collections.abc import Sequence

from hub.bus import LOOP_PUBLISH, TELEMETRY_PUBLISH, open_session, payload_bytes
from hub.config import BusSection, ConfigError, EndpointSection, ExperimentConfig
from hub.protocol import (
    INPUT_TYPE,
    OUTPUT_TYPE,
    Description,
    Keys,
    Message,
    ProtocolError,
)
from hub.scheduling import (
    Scheduling,
    available_cpus,
    place_threads,
    raise_threads,
    restore_placement,
    restore_threads,
)

log = logging.getLogger(__name__)

# An input this many steps ahead of the last one is dropped as "future".
FUTURE_HORIZON_STEPS = 1000


class Endpoint(abc.ABC):
    """A body or culture served on the bus.

    Parameters
    ----------
    id : str
        Which body or culture this is (``nv/<s>/<role>/<id>/...``).
    input_timeout_s : float
        With no input for this long, :meth:`on_input_timeout` is called once
        (a device body stops its motors there).
    """

    role: str = ""  # "body" or "culture", set by subclasses
    kind: str = ""  # e.g. "sim_robot", "sim_network", "khepera"

    def __init__(self, id: str = "0", *, input_timeout_s: float = 1.0):
        if self.role not in INPUT_TYPE:
            raise TypeError(f"{type(self).__name__}.role must be 'body' or 'culture'")
        self.id = str(id)
        self.input_timeout_s = input_timeout_s
        self.dropped: Counter[str] = Counter()
        self.busy_s = 0.0  # time spent in step(): the model's or device's share of a run
        self.steps = 0
        self.last_step = -1
        self._stop = threading.Event()
        self._session = None
        self._telemetry: dict = {}
        self.keys = Keys()
        self.scheduling = Scheduling("normal", reason="not serving")

    # ------------------------------------------------------------ for subclasses

    @classmethod
    def from_config(cls, section: EndpointSection, cfg: ExperimentConfig) -> Endpoint:
        """Build from the experiment's ``[body]``/``[culture]`` section.

        Subclasses read ``section.params`` here, raising
        :class:`~hub.config.ConfigError` that names ``<role>.params.<key>``.
        """
        if section.params:
            raise ConfigError(
                f"{cls.role}.params: {cls.__name__} takes no parameters, "
                f"got {sorted(section.params)}"
            )
        return cls(section.id)

    @abc.abstractmethod
    def describe(self) -> Description:
        """What this endpoint is: its kind and geometry (channels or sensors)."""

    @abc.abstractmethod
    def step(self, message: Message) -> Message:
        """Apply one step's input, advance one loop period, return the output.

        ``message`` is a validated :class:`~hub.protocol.MotorCommand` (body)
        or :class:`~hub.protocol.Stimulation` (culture); the returned
        :class:`~hub.protocol.SensorReading` or
        :class:`~hub.protocol.SpikeBatch` must carry the same ``step``.
        """

    def warm_up(self) -> None:
        """Run what the first step would compile or load, leaving the state as it was
        (called before the endpoint declares itself alive). Default: nothing."""

    def on_input_timeout(self) -> None:
        """No input for ``input_timeout_s``: make the device safe. Default: nothing."""

    def close(self) -> None:
        """Stop the device and release it. Default: nothing."""

    def publish_telemetry(self, key: str, message: Message) -> None:
        """Publish an observer-only message (newest wins; never blocks the loop)."""
        if self._session is None:
            return
        publisher = self._telemetry.get(key)
        if publisher is None:
            publisher = self._session.declare_publisher(key, **TELEMETRY_PUBLISH)
            self._telemetry[key] = publisher
        publisher.put(message.encode())

    # ------------------------------------------------------------ serving

    def description(self) -> Description:
        """:meth:`describe` with this endpoint's counters: drops by kind, steps, busy time
        (inside :meth:`step`) and CPU time of the process so far."""
        counters = {
            "dropped": dict(self.dropped),
            "steps": self.steps,
            "busy_s": self.busy_s,
            "cpu_s": time.process_time(),  # the whole process, every thread
            "scheduling": self.scheduling.to_dict(),
        }
        cpus = available_cpus()
        if cpus is not None:
            counters["cpus"] = sorted(cpus)  # those this process could run on
        return dataclasses.replace(self.describe(), counters=counters)

    def request_stop(self) -> None:
        """Ask :meth:`serve` to return (thread-safe; used by signal handlers)."""
        self._stop.set()

    def handle(self, raw: bytes) -> Message | None:
        """Validate one raw input and step on it; None if it was dropped."""
        try:
            message = INPUT_TYPE[self.role].decode(raw)
        except ProtocolError as exc:
            self._drop(exc.kind, str(exc))
            return None
        if message.step <= self.last_step:
            self._drop("stale", f"step {message.step} after step {self.last_step}")
            return None
        if message.step > self.last_step + FUTURE_HORIZON_STEPS:
            self._drop("future", f"step {message.step} far ahead of step {self.last_step}")
            return None
        self.last_step = message.step
        t0 = time.perf_counter()
        output = self.step(message)
        self.busy_s += time.perf_counter() - t0
        self.steps += 1
        if not isinstance(output, OUTPUT_TYPE[self.role]) or output.step != message.step:
            raise TypeError(
                f"{type(self).__name__}.step must return a {OUTPUT_TYPE[self.role].__name__} "
                f"for step {message.step}"
            )
        return output

    def _drop(self, kind: str, detail: str) -> None:
        if not self.dropped[kind]:
            log.warning("%s/%s dropped a message (%s): %s", self.role, self.id, kind, detail)
        self.dropped[kind] += 1

    def serve(
        self,
        bus: BusSection,
        *,
        install_signals: bool = True,
        realtime_priority: int = 0,
        cpus: Sequence[int] = (),
    ) -> int:
        """Serve on the bus until stopped; return the exit status (0 on a clean stop).

        ``realtime_priority`` > 0 puts this process's threads under ``SCHED_FIFO`` at that
        priority once warmed up (see :mod:`hub.scheduling`; refused: ordinary scheduling).
        ``cpus`` keeps the process's threads on those CPUs (``<role>.cpus``; empty: the
        OS decides).
        """
        if install_signals:
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, lambda *_: self.request_stop())
        keys = self.keys = Keys(bus.session)
        placement = place_threads(f"{self.role}.cpus", cpus)
        if placement.reason:
            log.warning("%s.cpus not applied: %s", self.role, placement.reason)
        try:
            self.warm_up()  # so that the first realtime steps are not late
            session = self._session = open_session(bus, listener=False)
        except BaseException:
            restore_placement(placement)
            raise
        # Once Zenoh's threads exist: the policy is not inherited by new threads.
        self.scheduling = raise_threads(realtime_priority)
        if realtime_priority and self.scheduling.policy != "fifo":
            log.warning("%s/%s: %s", self.role, self.id, self.scheduling.reason)
        publisher = session.declare_publisher(keys.output(self.role, self.id), **LOOP_PUBLISH)
        # Inputs are stepped on in the subscriber's own callback thread (one thread, so in
        # order): handing them to this thread would cost a wake-up per step. This thread
        # only watches for the input timeout and the stop request.
        lock = threading.Lock()  # one of step, describe, timeout and close at a time
        state = {"last_input": time.monotonic(), "serving": True}
        failures: list[BaseException] = []

        def on_input(sample) -> None:
            raw = payload_bytes(sample)
            with lock:
                if not state["serving"]:
                    return
                try:
                    output = self.handle(raw)
                    if output is not None:
                        publisher.put(output.encode())
                        state["last_input"] = time.monotonic()
                        if self.steps == 1:  # this callback thread has started now
                            self.scheduling.include_new_threads()
                except BaseException as exc:  # handed to serve(), which re-raises it
                    state["serving"] = False
                    failures.append(exc)
                    self._stop.set()

        def on_describe(query) -> None:
            with lock:
                query.reply(query.key_expr, self.description().encode())

        try:
            # Zenoh undeclares what is garbage-collected: keep every declaration.
            declared = [  # noqa: F841
                session.declare_subscriber(keys.input(self.role, self.id), on_input),
                session.declare_queryable(keys.describe(self.role, self.id), on_describe),
            ]
            # Declared last: when the hub sees us alive, we already listen.
            token = session.liveliness().declare_token(keys.alive(self.role, self.id))  # noqa: F841
            gc.collect()
            gc.freeze()  # the model is long-lived: keep full collections short
            log.info("%s/%s (%s) ready on session %s", self.role, self.id, self.kind, bus.session)
            timed_out = False
            while not self._stop.wait(0.05):
                with lock:
                    idle_s = time.monotonic() - state["last_input"]
                    if idle_s <= self.input_timeout_s:
                        timed_out = False
                    elif not timed_out:
                        timed_out = True
                        self.on_input_timeout()
        finally:
            try:
                with lock:
                    state["serving"] = False
                    self.close()
            finally:
                self._telemetry.clear()
                self._session = None
                session.close()
                restore_threads(self.scheduling)
                restore_placement(placement)
        if failures:
            raise failures[0]
        if self.dropped:
            log.info("%s/%s dropped: %s", self.role, self.id, dict(self.dropped))
        return 0
