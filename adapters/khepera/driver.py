"""A Khepera driven over its serial link at the link's own pace, on a thread of its own.

Each cycle of :class:`KheperaDriver`'s thread sends the wheel speeds if they changed
(``D``), reads the proximity sensors (``N``) and the position counters (``H``; a Khepera
III's ``R``), and keeps
the freshest :class:`Reading`. The loop's steps never wait for the serial line: they set the
speeds and take the freshest reading, whose age they report.

Safety lives here, not on the bus: the thread stops the motors (``D,0,0``) when no speed
command came for ``watchdog_s``; :meth:`KheperaDriver.stop_motors` stops them at once;
a link fault stops them if the link still allows and is then reported. Each cycle beats
the link's stop guard (:mod:`adapters.guard`), which stops them from outside this
process when the beats stop (the process frozen or this thread hung).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from adapters.khepera.calibration import IRCalibration, Odometry
from adapters.khepera.link import LinkFault, SerialLink
from adapters.khepera.protocol import COUNTER_COMMANDS, N_PROXIMITY, ReplyError
from hub.endpoint import DeviceFault

log = logging.getLogger(__name__)

#: cycles timed when the driver connects, for the cycle time it describes
CYCLES_MEASURED = 5


@dataclass(frozen=True)
class Reading:
    """What one cycle read: proximity values, their distances and the odometry pose."""

    t_mono_s: float  # time.monotonic() when the proximity reply arrived
    ir_values: np.ndarray
    ranges_m: np.ndarray
    pose: np.ndarray  # x_m, y_m, heading_rad


@dataclass(frozen=True)
class WheelUnits:
    """The robot's wheel-speed units: ``speed_unit_mps`` per unit, ``max_units`` at most."""

    speed_unit_mps: float
    max_units: int

    @classmethod
    def of(cls, model) -> WheelUnits:
        """The units of a :class:`devices.khepera.KheperaModel`."""
        return cls(model.speed_unit_mps, model.max_speed_units)

    @property
    def max_mps(self) -> float:
        """The fastest a wheel may be driven (m/s): ``max_units`` units."""
        return self.speed_unit_mps * self.max_units

    def to_units(self, speed_mps: float) -> tuple[int, bool]:
        """The nearest speed in units, clamped to the limit; and whether it was clamped."""
        units = round(speed_mps / self.speed_unit_mps)
        clamped = max(-self.max_units, min(self.max_units, units))
        return clamped, clamped != units


class KheperaDriver:
    """Polls a Khepera over ``link`` and applies wheel speeds (thread-safe).

    Parameters
    ----------
    link : SerialLink
        The robot's serial link.
    units : WheelUnits
        Its wheel-speed units.
    calibration : IRCalibration
        Proximity values → distances.
    odometry : Odometry
        Counters → pose.
    watchdog_s : float
        Motors stopped when no speed command came for this long.
    on_fault : callable, optional
        Called once with the :class:`LinkFault` when the link fails (from the driver's
        thread), after the motors were stopped if the link allowed.
    """

    def __init__(
        self,
        link: SerialLink,
        *,
        units: WheelUnits,
        calibration: IRCalibration,
        odometry: Odometry,
        watchdog_s: float = 0.5,
        on_fault: Callable[[LinkFault], None] | None = None,
    ):
        self.link, self.units, self.calibration, self.odometry = link, units, calibration, odometry
        self.watchdog_s = watchdog_s
        self.on_fault = on_fault
        self.counts: Counter[str] = Counter()  # clamps, watchdog stops, failed cycles
        self.cycles_s: deque[float] = deque(maxlen=1000)
        self.ages_s: deque[float] = deque(maxlen=100_000)
        self.cycle_ms = 0.0  # measured when connecting
        self.fault: LinkFault | None = None
        self._latest: Reading | None = None
        self._target = (0, 0)
        self._sent: tuple[int, int] | None = None
        self._commanded_at = time.monotonic()
        self._lock = threading.Lock()
        # held from a speed's choice to its write: a stop waits for a write under way, so
        # that no speed read before the stop reaches the robot after it
        self._motor = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------ life

    def connect(self) -> None:
        """Stop the motors, check the robot answers, time a few cycles, and start polling.

        Raises
        ------
        LinkFault
            The robot does not answer.
        ReplyError
            It answers, but not the protocol.
        """
        self.link.transact("B")
        self.stop_motors()
        t0 = time.perf_counter()
        for _ in range(CYCLES_MEASURED):
            self._sent = None  # the worst case: a speed write in every cycle
            self._cycle()
        self.cycle_ms = (time.perf_counter() - t0) / CYCLES_MEASURED * 1e3
        self.cycles_s.clear()
        self._thread = threading.Thread(target=self._poll, name="khepera-serial", daemon=True)
        self._thread.start()

    def reset(self, pose) -> None:
        """Motors stopped, position counters zeroed, odometry from ``pose``."""
        self.stop_motors()
        self.link.transact(COUNTER_COMMANDS[self.link.dialect][0], 0, 0)
        with self._lock:
            self.odometry.reset(pose, (0, 0))

    def close(self) -> None:
        """Stop polling, stop the motors if the link allows, release the port."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self.link.rest()  # no more beats: not a freeze
        try:
            self.stop_motors()
        except (LinkFault, ReplyError) as exc:
            log.warning("could not stop the motors at close: %s", exc)
        with self._motor:  # a stop from another thread goes before, or finds it closed
            self.link.close()

    # ------------------------------------------------------------ the loop's side

    def command(self, left_mps: float, right_mps: float) -> bool:
        """Set the wheel speeds (sent by the next cycle); True when one was clamped.

        Each call restarts the motor watchdog. Called from the loop's thread; never waits
        for the serial line.

        Parameters
        ----------
        left_mps, right_mps : float
            The wheels' speeds, rounded to the robot's units and clamped to its limit.
        """
        left, clamp_l = self.units.to_units(left_mps)
        right, clamp_r = self.units.to_units(right_mps)
        with self._lock:
            self._target = (left, right)
            self._commanded_at = time.monotonic()
            if clamp_l or clamp_r:
                self.counts["clamped"] += 1
        return clamp_l or clamp_r

    def stop_motors(self) -> None:
        """``D,0,0`` now, on the caller's thread (waits for the link, not for a cycle).
        Nothing once the link is closed: :meth:`close` stopped the motors first, or said
        that it could not (the hub's going and the endpoint's end may come in either order,
        each making the robot safe).

        Raises
        ------
        LinkFault
            The link failed.
        """
        with self._lock:
            self._target = (0, 0)
        with self._motor:  # after a speed write under way, never before it
            if self.link.closed:
                return
            self.link.transact("D", 0, 0)
            with self._lock:
                self._sent = (0, 0)

    def latest(self) -> Reading | None:
        """The freshest reading (None before the first)."""
        with self._lock:
            return self._latest

    def note_age(self, age_s: float) -> None:
        """Count the age (s) of a reading a step answered with, for :meth:`stats`."""
        with self._lock:
            self.ages_s.append(age_s)

    # ------------------------------------------------------------ the link's side

    def _poll(self) -> None:
        while not self._stop.is_set():
            try:
                self._cycle()
            except ReplyError:
                self.counts["failed_cycles"] += 1  # the link counted and logged the line
            except DeviceFault as exc:  # the link failed, or the stop guard was lost
                self._fail(exc)
                return

    def _cycle(self) -> None:
        t0 = time.monotonic()
        if self.link.beat():  # the stop guard stopped the robot while this process stood
            with self._lock:
                self._sent = None  # so the speeds go again (or stay stopped: the watchdog)
                self.counts["guard_stops"] += 1
            log.warning("the stop guard stopped the motors while this process was frozen")
        with self._motor:
            with self._lock:
                target = self._target
                if target != (0, 0) and t0 - self._commanded_at > self.watchdog_s:
                    target = self._target = (0, 0)
                    self.counts["watchdog_stops"] += 1
                    log.warning("no motor command for %.2f s: motors stopped", self.watchdog_s)
                send = target != self._sent
            if send:
                self.link.transact("D", *target)
                with self._lock:
                    self._sent = target
        proximity = self.link.transact("N")
        t_read = time.monotonic()
        counters = self.link.transact(COUNTER_COMMANDS[self.link.dialect][1]).fields
        values = np.asarray(proximity.fields[: N_PROXIMITY[self.link.dialect]], dtype=np.float32)
        with self._lock:
            pose = self.odometry.update(counters)
            self._latest = Reading(t_read, values, self.calibration.range_m(values), pose)
            self.cycles_s.append(time.monotonic() - t0)

    def _fail(self, exc: DeviceFault) -> None:
        self.link.rest()  # this thread ends: its beats stop, and not for a freeze
        self.fault = exc
        log.error("%s", exc)
        try:
            self.link.transact("D", 0, 0)
        except (LinkFault, ReplyError):
            pass  # the link is gone: nothing more can reach the robot
        if self.on_fault is not None:
            self.on_fault(exc)

    def stats(self) -> dict:
        """Cycle time and reading age (ms; median and 99th percentile) and the counts."""
        with self._lock:
            cycles, ages = np.array(self.cycles_s), np.array(self.ages_s)
            out = {"cycle_ms_measured": self.cycle_ms, **self.counts, **self.link.counts}
            if self.link.guard is not None:
                out["guards_replaced"] = self.link.guard.replaced
        for name, data in (("cycle_ms", cycles), ("reading_age_ms", ages)):
            if data.size:
                out[f"{name}_p50"] = float(np.percentile(data, 50) * 1e3)
                out[f"{name}_p99"] = float(np.percentile(data, 99) * 1e3)
        return out
