"""What the hub sends each step: the schemes' output, checked, or the policy's stand-in.

Pure (no bus, no clock): given the step and the reply it depends on — or None when that
reply is missing — :class:`InputPolicy` returns the next input. The body's motor command
of step k is decoded from the culture's spikes of step k−1, the culture's stimulation of
step k coded from the body's sensors of step k−1 (ARCHITECTURE.md, "The loop"); when the
reply is missing, ``[policy]`` decides (``missing_spikes``: stop the robot or hold its
last command; ``missing_sensors``: no stimulation or code the last reading again). A
scheme's output over the endpoint's limits is refused whole (never clipped) and counted.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable

from hub.config import ConfigError, ExperimentConfig
from hub.limits import StimulationLimits, motor_violation
from hub.protocol import (
    Description,
    MotorCommand,
    SensorReading,
    SpikeBatch,
    StepWindow,
    Stimulation,
)
from hub.schemes import SchemeContext, load_scheme

log = logging.getLogger(__name__)


class SchemeError(RuntimeError):
    """A coding or decoding scheme raised, or returned something other than the input
    asked for: the run ends as a fault (the scheme's traceback in the log)."""


def _raised(section: str, spec: str, when: str, exc: Exception) -> SchemeError:
    """The error of a scheme that raised ``exc``, its traceback logged."""
    log.error("%s.scheme %s raised %s", section, spec, when, exc_info=exc)
    return SchemeError(
        f"{section}.scheme {spec} raised {when}: {type(exc).__name__}: {exc} "
        "(its traceback is logged)"
    )


class InputPolicy:
    """The inputs of each step of one run, from the schemes and the ``[policy]`` section.

    Parameters
    ----------
    cfg : ExperimentConfig
        The experiment (its ``coding``, ``decoding`` and ``policy`` sections).
    body, culture : Description
        What the endpoints described (schemes and limits are built on them).
    run : str
        The run id every input carries.
    on_refused : callable, optional
        Called with the scheme's name and why, for each output refused over a limit.

    Attributes
    ----------
    refused : Counter
        Scheme outputs refused over a limit, by scheme (``coding``, ``decoding``).
    """

    def __init__(
        self,
        cfg: ExperimentConfig,
        body: Description,
        culture: Description,
        run: str,
        on_refused: Callable[[str, str], None] | None = None,
    ):
        common = dict(
            body=body, culture=culture, period_ms=cfg.loop.period_ms, seed=cfg.experiment.seed
        )
        built = {}
        for section in ("coding", "decoding"):
            spec, params = getattr(cfg, section).scheme, getattr(cfg, section).params
            factory = load_scheme(spec, section)
            try:
                built[section] = factory(SchemeContext(params=params, section=section, **common))
            except ConfigError:  # a parameter that does not fit the descriptions
                raise
            except Exception as exc:
                raise _raised(section, spec, "when built", exc) from None
        self.coder, self.decoder = built["coding"], built["decoding"]
        self.specs = {"coding": cfg.coding.scheme, "decoding": cfg.decoding.scheme}
        self.policy = cfg.policy
        self.body = body
        self.run = run
        self.period_s = cfg.loop.period_ms / 1e3
        self._window: StepWindow | None = None
        self.stim_limits = StimulationLimits(culture)
        self.last_motor = MotorCommand.stop(self.window(0))
        self.last_sensors: SensorReading | None = None
        self.refused: Counter[str] = Counter()
        self.on_refused = on_refused

    def window(self, k: int) -> StepWindow:
        """Step ``k`` of this run (the latest kept: both inputs of a step ask for it)."""
        window = self._window
        if window is None or window.step != k:
            window = self._window = StepWindow.of(self.run, k, self.period_s)
        return window

    def motor_for(self, k: int, spikes: SpikeBatch | None) -> MotorCommand:
        """The body's input of step ``k``, from the culture's spikes of step ``k``−1.

        Step 0 and a decoded command over ``max_wheel_mps`` (refused, counted) stop the
        robot.

        Parameters
        ----------
        k : int
            The step.
        spikes : SpikeBatch or None
            The culture's reply of step ``k``−1; None when it is missing
            (``policy.missing_spikes`` decides).

        Raises
        ------
        SchemeError
            The decoder raised, or returned something other than this step's
            MotorCommand.
        """
        window = self.window(k)
        if k == 0:
            return MotorCommand.stop(window)
        if spikes is not None:
            try:
                motor = self.decoder(spikes, window)
            except Exception as exc:
                raise _raised("decoding", self.specs["decoding"], f"at step {k}", exc) from None
            motor = _checked(motor, MotorCommand, window)
            why = motor_violation(motor, self.body)
            if why is None:
                self.last_motor = motor
            else:  # refused, never clipped: the robot stops for this step
                self._refuse("decoding", f"step {k}: {why}")
                self.last_motor = MotorCommand.stop(window)
        elif self.policy.missing_spikes == "stop_robot":
            self.last_motor = MotorCommand.stop(window)
        else:  # hold
            m = self.last_motor
            self.last_motor = MotorCommand(
                **window.stamp,
                left_mps=m.left_mps,
                right_mps=m.right_mps,
                v_mps=m.v_mps,
                omega_rad_s=m.omega_rad_s,
            )
        return self.last_motor

    def stim_for(self, k: int, sensors: SensorReading | None) -> Stimulation:
        """The culture's input of step ``k``, from the body's sensors of step ``k``−1.

        Step 0 and a coded stimulation over the culture's limits (refused, counted) are no
        stimulation; a stimulation returned is counted towards the rate limit.

        Parameters
        ----------
        k : int
            The step.
        sensors : SensorReading or None
            The body's reply of step ``k``−1; None when it is missing
            (``policy.missing_sensors`` decides).

        Raises
        ------
        SchemeError
            The coder raised, or returned something other than this step's Stimulation.
        """
        window = self.window(k)
        if k == 0:
            return Stimulation.none(window)
        if sensors is not None:
            self.last_sensors = sensors
        elif self.policy.missing_sensors == "zero_stim" or self.last_sensors is None:
            return Stimulation.none(window)
        try:
            stim = self.coder(self.last_sensors, window)
        except Exception as exc:
            raise _raised("coding", self.specs["coding"], f"at step {k}", exc) from None
        stim = _checked(stim, Stimulation, window)
        why = self.stim_limits.violation(stim)
        if why is not None:  # refused, never clipped: no stimulation this step
            self._refuse("coding", f"step {k}: {why}")
            return Stimulation.none(window)
        self.stim_limits.accept(stim)
        return stim

    def _refuse(self, scheme: str, detail: str) -> None:
        self.refused[scheme] += 1
        if self.on_refused is not None:
            self.on_refused(scheme, detail)


def _checked(message, kind, window: StepWindow):
    if (
        not isinstance(message, kind)
        or message.step != window.step
        or message.run != window.run
        or message.t0_s != window.t0_s
        or message.t1_s != window.t1_s
    ):
        raise SchemeError(
            f"scheme returned {message!r}, expected a {kind.__name__} for step "
            f"{window.step} (window {window})"
        )
    return message
