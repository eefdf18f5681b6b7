"""A real Khepera robot as the loop's body (``[body] kind = "khepera"``).

Each step applies the hub's :class:`~hub.protocol.MotorCommand` (m/s → the robot's units,
clamped to its limits, the clamp counted) and answers at once with the freshest reading of
the serial thread (:mod:`adapters.khepera.driver`): IR distances through the calibration
table, the odometry pose, ``t_s`` the run time the reading was taken and ``age_s`` its age.

Parameters (``[body.params]``; docs in docs/khepera.md):

``port`` (required), ``dialect`` (``khepera2``, the default, or ``khepera3``: the robot's
model), ``baud`` (9600, 19200, 38400, 57600, 115200; default 9600 for a Khepera II, 115200
for a Khepera III), ``stop_bits`` (1 or 2; default 2 for a Khepera II, 1 for a Khepera III),
``timeout_s`` (one reply; default 0.25), ``silent_s`` (no valid reply for this long is a
fault; default 1.0), ``watchdog_s`` (no motor command for this long stops the motors;
default 0.5; at least two loop periods, at most 5 s or four periods), ``freeze_s`` (the
adapter's serial thread silent for this long — the process frozen or hung — and its stop
guard, a process of its own, stops the motors; default 1.0; at least two reply timeouts and
three serial cycles; 0 turns it off), ``ir_table_file`` (a lab's calibration, CSV
``distance_m,value``; default the published Khepera II table; required for a Khepera III,
which has none published), ``start_pose`` (``[x_m, y_m, heading_deg]`` odometry starts from;
default ``[0, 0, 0]``), ``world`` (a world file drawing the lab's arena: used only by the
run's summary, for the trajectory figure and the arena metrics).

A device runs in real time only: a lockstep run is refused, at ``neuvision run`` before
anything starts and by the endpoint itself.
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path

import numpy as np

from adapters.khepera.calibration import IRCalibration, Odometry
from adapters.khepera.driver import KheperaDriver, WheelUnits
from adapters.khepera.link import BAUDS, LinkFault, SerialLink, open_port
from adapters.khepera.protocol import DIALECTS, ReplyError
from devices import khepera
from hub.config import ConfigError, EndpointSection, ExperimentConfig, check_value
from hub.endpoint import Endpoint, RunRefused
from hub.protocol import Description, MotorCommand, RunStart, SensorReading, StepWindow

log = logging.getLogger(__name__)

#: the longest watchdog_s allowed at periods under 1.25 s (else four periods)
WATCHDOG_MAX_S = 5.0


def watchdog_problem(watchdog_s: float, period_ms: float) -> str | None:
    """Why a motor watchdog of ``watchdog_s`` does not suit a loop of ``period_ms``, or None.

    The watchdog is also the endpoint's input timeout: under two periods the motors would
    stop between steps. It is also how long the robot drives on blind when its commands
    stop (the hub killed, the network cut): at most :data:`WATCHDOG_MAX_S`, or four periods
    if longer.

    Parameters
    ----------
    watchdog_s : float
        No motor command for this long stops the motors.
    period_ms : float
        The loop's period.
    """
    least_s = 2 * period_ms / 1e3
    if watchdog_s < least_s:
        return (
            f"watchdog_s {watchdog_s:g} s is under two loop periods ({least_s:g} s): "
            "the motors would stop between steps"
        )
    most_s = max(WATCHDOG_MAX_S, 4 * period_ms / 1e3)
    if watchdog_s > most_s:
        return (
            f"watchdog_s {watchdog_s:g} s: the robot would drive on that long with no "
            f"command (the hub gone, the network cut); at most {most_s:g} s "
            f"({WATCHDOG_MAX_S:g} s, or four loop periods if longer)"
        )
    return None


LOCKSTEP_REFUSAL = (
    "a Khepera is a real device: it moves in real time and cannot wait for a lockstep "
    'loop; set loop.mode = "realtime"'
)
DEFAULTS = {
    "baud": None,  # the model's (devices.khepera.MODELS)
    "stop_bits": None,
    "timeout_s": 0.25,
    "silent_s": 1.0,
    "watchdog_s": 0.5,
    "freeze_s": 1.0,
    "dialect": "khepera2",
    "ir_table_file": None,
    "start_pose": [0.0, 0.0, 0.0],
    "world": None,
}


class KheperaEndpoint(Endpoint):
    """A Khepera II or III on a serial line, served as a body.

    Parameters
    ----------
    driver : KheperaDriver
        Connected (or connected by :meth:`warm_up`).
    id : str
        Which body this is on the bus.
    start_pose : (x_m, y_m, heading_rad)
        Where odometry starts each run.

    The robot's model (its body, for ``describe``) is that of the link's dialect.
    """

    role, kind = "body", "khepera"

    def __init__(self, driver: KheperaDriver, id: str = "0", *, start_pose=(0.0, 0.0, 0.0)):
        super().__init__(id, input_timeout_s=driver.watchdog_s)
        self.driver = driver
        self.model = khepera.MODELS[driver.link.dialect]
        self.start_pose = tuple(float(v) for v in start_pose)
        self._origin_s = math.inf  # run time 0 on time.monotonic()'s clock
        driver.on_fault = self._on_fault

    @classmethod
    def check_config(cls, section: EndpointSection, cfg: ExperimentConfig) -> dict:
        """Check ``[body.params]`` and the loop's mode without opening the port.

        Parameters
        ----------
        section : EndpointSection
            The ``[body]`` section; its ``params`` are checked.
        cfg : ExperimentConfig
            The whole experiment: its loop's mode, and its period for ``watchdog_s``.

        Returns
        -------
        dict
            Every key of ``[body.params]``, the defaults filled in (``baud`` and
            ``stop_bits`` the model's) and the values typed.

        Raises
        ------
        ConfigError
            Naming ``body.params.<key>``, or ``loop.mode`` for a lockstep run.
        """
        if cfg.loop.mode != "realtime":
            raise ConfigError(f"loop.mode: {LOCKSTEP_REFUSAL}")
        params = dict(section.params)
        unknown = sorted(set(params) - set(DEFAULTS) - {"port"})
        if unknown:
            raise ConfigError(f"body.params: unknown key(s) {unknown} for kind khepera")
        if "port" not in params:
            raise ConfigError("body.params.port: the serial port of the robot is required")
        out = {**DEFAULTS, **params}
        out["port"] = check_value("body.params.port", str, out["port"])
        if not out["port"].strip():
            raise ConfigError("body.params.port: the serial port of the robot is required, got ''")
        if out["dialect"] not in DIALECTS:
            raise ConfigError(
                f"body.params.dialect must be one of {DIALECTS}, got {out['dialect']!r}"
            )
        model = khepera.MODELS[out["dialect"]]
        out["baud"] = model.baud if out["baud"] is None else out["baud"]
        out["stop_bits"] = model.stop_bits if out["stop_bits"] is None else out["stop_bits"]
        baud = check_value("body.params.baud", int, out["baud"])
        if baud not in BAUDS:
            raise ConfigError(f"body.params.baud must be one of {BAUDS}, got {baud}")
        if isinstance(out["stop_bits"], bool) or out["stop_bits"] not in (1, 2):
            raise ConfigError(f"body.params.stop_bits must be 1 or 2, got {out['stop_bits']!r}")
        for key in ("timeout_s", "silent_s", "watchdog_s"):
            out[key] = check_value(f"body.params.{key}", float, out[key], gt=0)
        why = watchdog_problem(out["watchdog_s"], cfg.loop.period_ms)
        if why is not None:
            raise ConfigError(f"body.params.{why}")
        # A failed reply and its retry are a live thread's longest silence; shorter, the
        # guard would stop a robot whose adapter is only waiting for its link.
        out["freeze_s"] = check_value("body.params.freeze_s", float, out["freeze_s"], ge=0)
        if 0 < out["freeze_s"] < 2 * out["timeout_s"]:
            raise ConfigError(
                f"body.params.freeze_s {out['freeze_s']:g} s is under two reply timeouts "
                f"(body.params.timeout_s {out['timeout_s']:g} s): the stop guard would stop "
                "the robot while the link retries; 0 turns it off"
            )
        pose = out["start_pose"]
        if not (isinstance(pose, list) and len(pose) == 3):
            raise ConfigError("body.params.start_pose must be [x_m, y_m, heading_deg]")
        out["start_pose"] = [
            check_value(f"body.params.start_pose[{i}]", float, v) for i, v in enumerate(pose)
        ]
        world = out["world"]
        if world is not None and not (isinstance(world, str) and Path(world).is_file()):
            raise ConfigError(f"body.params.world: no world file {world!r}")
        if out["ir_table_file"] is not None:
            IRCalibration.from_file(out["ir_table_file"])  # named ConfigError if bad
        elif model.ir_table is None:
            raise ConfigError(
                f"body.params.ir_table_file: no IR calibration of a {model.name} is published; "
                'measure your robot\'s and give the file (docs/khepera.md, "Calibration")'
            )
        return out

    @classmethod
    def from_config(cls, section: EndpointSection, cfg: ExperimentConfig) -> KheperaEndpoint:
        p = cls.check_config(section, cfg)
        model = khepera.MODELS[p["dialect"]]
        calibration = (
            IRCalibration.from_file(p["ir_table_file"])
            if p["ir_table_file"]
            else IRCalibration(model.ir_table)
        )
        port = open_port(
            p["port"], baud=p["baud"], stop_bits=p["stop_bits"], timeout_s=p["timeout_s"]
        )
        link = SerialLink(
            port, timeout_s=p["timeout_s"], silent_s=p["silent_s"], dialect=p["dialect"]
        )
        # the motors stopped even if this process is killed outright, or frozen
        link.guard_motors(freeze_s=p["freeze_s"])
        driver = KheperaDriver(
            link,
            units=WheelUnits.of(model),
            calibration=calibration,
            odometry=Odometry(model.pulse_m, model.wheel_base_m),
            watchdog_s=p["watchdog_s"],
        )
        x, y, heading_deg = p["start_pose"]
        return cls(driver, section.id, start_pose=(x, y, math.radians(heading_deg)))

    # ------------------------------------------------------------ the endpoint

    def warm_up(self) -> None:
        """Connect: the robot stopped, answering, its link's cycle timed."""
        if self.driver.cycle_ms == 0.0:
            link = self.driver.link
            try:
                self.driver.connect()
            except ReplyError as exc:  # something answers, but not as this robot
                raise LinkFault(
                    f"the device on {link.name} does not answer as a {self.model.name} "
                    f"({link.dialect} dialect): {exc}. Is it that robot, switched on, at "
                    "body.params.baud?"
                ) from None
            log.info("khepera on %s: serial cycle %.1f ms", link.name, self.driver.cycle_ms)
            freeze_s = link.guard.freeze_s if link.guard is not None else 0.0
            if 0 < freeze_s < 3 * self.driver.cycle_ms / 1e3:
                raise ConfigError(
                    f"body.params.freeze_s {freeze_s:g} s is under three serial cycles "
                    f"({self.driver.cycle_ms:.0f} ms each, measured on {link.name}): the stop "
                    "guard would stop the robot between cycles"
                )

    def describe(self) -> Description:
        self.warm_up()
        return Description(
            role="body",
            id=self.id,
            kind=self.kind,
            sensor_angles_rad=np.radians(self.model.sensor_facings_deg),
            max_range_m=self.driver.calibration.max_range_m,
            wheel_base_m=self.model.wheel_base_m,
            radius_m=self.model.radius_m,
            max_wheel_mps=self.driver.units.max_mps,
            realtime_only=True,
            cycle_ms=self.driver.cycle_ms,
        )

    def description(self) -> Description:
        desc = super().description()
        desc.counters["device"] = self.driver.stats()
        return desc

    def start_run(self, run: RunStart) -> None:
        if run.mode != "realtime":
            raise RunRefused(LOCKSTEP_REFUSAL)
        # The run's period is the hub's, announced here: this endpoint's own experiment
        # file (checked at start-up) may be another's.
        why = watchdog_problem(self.driver.watchdog_s, run.period_ms)
        if why is not None:
            raise RunRefused(f"{why} (the run's period is {run.period_ms:g} ms)")
        if self.driver.fault is not None:
            raise RunRefused(f"the serial link failed: {self.driver.fault}")
        self._origin_s = math.inf
        try:
            self.driver.reset(self.start_pose)
        except (LinkFault, ReplyError) as exc:
            raise RunRefused(f"the robot did not reset: {exc}") from None

    def step(self, m: MotorCommand, window: StepWindow) -> SensorReading:
        now = time.monotonic()
        self.driver.command(m.left_mps, m.right_mps)
        reading = self.driver.latest()
        age_s = max(0.0, now - reading.t_mono_s)
        self.driver.note_age(age_s)
        # Run time 0 on this clock: an input arrives at its window's start or later, so the
        # earliest estimate is the best; readings' run times then never go backwards.
        self._origin_s = min(self._origin_s, now - window.t0_s)
        t_s = min(max(0.0, reading.t_mono_s - self._origin_s), window.t1_s)
        return SensorReading(
            step=m.step,
            run=window.run,
            t_s=t_s,
            ranges_m=reading.ranges_m,
            pose=reading.pose,
            contact=False,  # a Khepera has no contact sensor
            age_s=age_s,
        )

    def make_safe(self) -> None:
        """``D,0,0`` now (not at the next cycle)."""
        try:
            self.driver.stop_motors()
        except (LinkFault, ReplyError) as exc:
            log.error("could not stop the motors: %s", exc)

    def close(self) -> None:
        self.driver.close()

    def _on_fault(self, exc: LinkFault) -> None:
        """The link failed (the driver tried a last stop): stop serving, named as a fault."""
        self.request_stop()

    def serve(self, *args, **kwargs) -> int:
        """:meth:`Endpoint.serve`; a link fault ends it with that fault raised."""
        try:
            status = super().serve(*args, **kwargs)
        except BaseException:
            self.driver.close()  # whatever ended it, the motors stop if the link allows
            raise
        if self.driver.fault is not None:
            raise self.driver.fault
        return status
