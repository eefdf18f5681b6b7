"""Small endpoints and schemes used as test fixtures (not product features).

They make the loop's order observable: the body reports, in its pose, the
step and the motor command it was given; the culture fires one spike per pulse
it was given; the schemes write the step of the message they were given into
what they produce. So a record shows which step's output fed which step's input.
"""

from __future__ import annotations

import ctypes
import dataclasses
import os
import signal
import time

import numpy as np

from hub.config import ConfigError
from hub.endpoint import DeviceFault, Endpoint
from hub.protocol import (
    Description,
    MotorCommand,
    SensorReading,
    SpikeBatch,
    StepWindow,
    Stimulation,
)

N_SENSORS = 3
MAX_RANGE_M = 1.0
N_CHANNELS = 4
# The echo body's decoder writes step numbers into wheel speeds: its limit is beyond them.
MAX_WHEEL_MPS = 1e9


class EchoBody(Endpoint):
    """pose = (step, left_mps received, right_mps received); ranges = 0.5 m."""

    role, kind = "body", "test_echo_body"

    def __init__(self, id="0", delay_ms: float = 0.0, late_every: int = 0):
        super().__init__(id)
        self.delay_ms = delay_ms
        self.late_every = late_every

    @classmethod
    def from_config(cls, section, cfg):
        unknown = set(section.params) - {"delay_ms", "late_every"}
        if unknown:
            raise ConfigError(f"body.params.{sorted(unknown)[0]} is not a parameter")
        return cls(section.id, **section.params)

    def describe(self):
        return Description(
            role="body",
            id=self.id,
            kind=self.kind,
            sensor_angles_rad=np.linspace(-1, 1, N_SENSORS),
            max_range_m=MAX_RANGE_M,
            wheel_base_m=0.05,
            radius_m=0.035,
            max_wheel_mps=MAX_WHEEL_MPS,
        )

    def step(self, m: MotorCommand, window) -> SensorReading:
        if self.delay_ms:
            time.sleep(self.delay_ms / 1e3)
        if self.late_every and m.step % self.late_every == self.late_every - 1:
            time.sleep(0.05)
        return SensorReading(
            step=m.step,
            run=window.run,
            t_s=window.t1_s,
            ranges_m=np.full(N_SENSORS, 0.5, np.float32),
            pose=np.array([m.step, m.left_mps, m.right_mps]),
            contact=False,
        )


class SlowToBuildBody(EchoBody):
    """An echo body whose building takes as long as a big model's: it writes
    ``params.built_file`` when it starts building, then builds for ``params.build_s``."""

    @classmethod
    def from_config(cls, section, cfg):
        params = dict(section.params)
        with open(params.pop("built_file"), "w") as f:
            f.write("building")
        time.sleep(params.pop("build_s", 60.0))
        return cls(section.id, **params)


class DeviceBody(EchoBody):
    """An echo body that describes itself as a real device with an 80 ms I/O cycle."""

    kind = "test_device_body"

    def describe(self):
        return dataclasses.replace(super().describe(), realtime_only=True, cycle_ms=80.0)


class FailingDeviceBody(EchoBody):
    """An echo body whose device fails at step ``params.fail_at`` (a serial line lost)."""

    kind = "test_failing_device_body"

    def __init__(self, id="0", fail_at: int = 20):
        super().__init__(id)
        self.fail_at = fail_at

    @classmethod
    def from_config(cls, section, cfg):
        return cls(section.id, **section.params)

    def step(self, m: MotorCommand, window) -> SensorReading:
        if m.step == self.fail_at:
            raise DeviceFault(f"the test device's line failed at step {m.step}")
        return super().step(m, window)


class BodyStoppedWhileBuilding(EchoBody):
    """An EchoBody whose model building gets SIGTERM where a library takes the
    KeyboardInterrupt raised for it (``body.params.where``):

    - ``"ctypes"``: inside a ctypes callback, which prints it as ignored and goes on (as
      numba loading its cache through llvmlite);
    - ``"exec"``: inside an exec() of a string (as a dataclass's generated methods), which
      CPython 3.11 notes as unhandled though it is caught later;
    - ``"error"``: inside a library that raises an error of its own instead.
    """

    def __init__(self, id="0", where="ctypes"):
        if where == "ctypes":
            ctypes.CFUNCTYPE(None)(_signal_self)()
        elif where == "exec":
            exec("_signal_self()", {"_signal_self": _signal_self})
        else:
            try:
                _signal_self()
            except KeyboardInterrupt:
                raise RuntimeError("a library's own error") from None
        super().__init__(id)

    @classmethod
    def from_config(cls, section, cfg):
        return cls(section.id, **section.params)


def _signal_self() -> None:
    os.kill(os.getpid(), signal.SIGTERM)
    sum(range(1000))  # the handler runs here


class EchoCulture(Endpoint):
    """One spike on channel 0 per pulse received, at the pulse's onset."""

    role, kind = "culture", "test_echo_culture"

    def describe(self):
        return Description(
            role="culture",
            id=self.id,
            kind=self.kind,
            channel=np.arange(N_CHANNELS),
            x_um=np.zeros(N_CHANNELS),
            y_um=np.arange(N_CHANNELS) * 100.0,
        )

    def step(self, s: Stimulation, window) -> SpikeBatch:
        n = s.n_pulses
        return SpikeBatch(
            **window.stamp,
            channel=np.zeros(n, np.uint32),
            t_ms=np.sort(s.onset_ms),
        )


def code_step_count(ctx):
    """Coder: as many pulses as the sensor reading's step (capped at 8), amplitude = step."""
    ctx.check_params(set())

    def coder(sensors, window):
        n = min(sensors.step, 8)
        return Stimulation(
            **window.stamp,
            channel=np.zeros(n, np.uint32),
            amplitude_ua=np.full(n, float(sensors.step), np.float32),
            width_ms=np.ones(n, np.float32),
            onset_ms=np.zeros(n, np.float32),
        )

    return coder


def code_wrong_step_at_20(ctx):
    """Coder with a bug: no pulses, and at step 20 the stimulation of step 21."""
    ctx.check_params(set())

    def coder(sensors, window):
        if window.step == 20:
            window = StepWindow.of(window.run, 21, window.period_s)
        return Stimulation.none(window)

    return coder


def decode_step(ctx):
    """Decoder: left_mps = step of the spike batch, right_mps = its spike count."""
    ctx.check_params(set())
    return lambda spikes, window: MotorCommand(
        **window.stamp, left_mps=float(spikes.step), right_mps=float(spikes.channel.size)
    )


def constant_drive(ctx):
    """Decoder: the same wheel speeds every step (``left_mps``, ``right_mps`` in params)."""
    ctx.check_params({"left_mps", "right_mps"})
    left = ctx.param("left_mps", 0.0)
    right = ctx.param("right_mps", 0.0)
    return lambda spikes, window: MotorCommand(**window.stamp, left_mps=left, right_mps=right)


def pulse_at_step(ctx):
    """Coder: one pulse (``channel``, ``amplitude_ua``, ``width_ms``) at ``step`` only."""
    ctx.check_params({"channel", "amplitude_ua", "width_ms", "step"})
    channel = ctx.param("channel", 0, kind=int)
    amplitude = ctx.param("amplitude_ua", 100.0)
    width = ctx.param("width_ms", 10.0)
    at = ctx.param("step", 10, kind=int)

    def coder(sensors, window):
        if window.step != at:
            return Stimulation.none(window)
        return Stimulation(
            **window.stamp,
            channel=[channel],
            amplitude_ua=[amplitude],
            width_ms=[width],
            onset_ms=[0],
        )

    return coder


class LargeCulture(Endpoint):
    """A culture of ``n_channels`` channels that fires ``spikes_per_step`` spikes every step,
    spread over its channels and its window: what a large culture's network burst puts on
    the wire (100,000 channels firing 3 spikes each make a 2.4 MB SpikeBatch)."""

    role, kind = "culture", "test_large_culture"

    def __init__(self, id="0", n_channels: int = 4096, spikes_per_step: int = 0):
        super().__init__(id)
        self.n_channels = n_channels
        self.spikes_per_step = spikes_per_step

    @classmethod
    def from_config(cls, section, cfg):
        unknown = set(section.params) - {"n_channels", "spikes_per_step"}
        if unknown:
            raise ConfigError(f"culture.params.{sorted(unknown)[0]} is not a parameter")
        return cls(section.id, **section.params)

    def describe(self):
        n = self.n_channels
        return Description(
            role="culture",
            id=self.id,
            kind=self.kind,
            channel=np.arange(n),
            x_um=np.arange(n) % 316 * 10.0,
            y_um=np.arange(n) // 316 * 10.0,
        )

    def step(self, s: Stimulation, window) -> SpikeBatch:
        n = self.spikes_per_step
        span_ms = window.period_s * 1e3
        return SpikeBatch(
            **window.stamp,
            channel=np.arange(n, dtype=np.uint32) % self.n_channels,
            t_ms=np.linspace(0.0, span_ms, n, endpoint=False, dtype=np.float32),
        )


class TrailingCulture(EchoCulture):
    """An echo culture that describes itself as answering each window after it has passed."""

    kind = "test_trailing_culture"

    def describe(self):
        return dataclasses.replace(super().describe(), answers_after_window=True)


class StreamingCulture(EchoCulture):
    """An echo culture that streams (contract v4): a spike on channel 1 late in each window
    goes first, as a part; the echo of the step's pulses follows in its batch."""

    kind = "test_streaming_culture"

    def step(self, s: Stimulation, window) -> SpikeBatch:
        late_ms = (window.t1_s - window.t0_s) * 1e3 * 0.9
        self.reply(SpikeBatch(**window.stamp, channel=[1], t_ms=[late_ms], partial=True))
        return super().step(s, window)


def build_fails(ctx):
    """A factory with a bug of its own: it reads a parameter it never got."""
    return ctx.params["gain"]


def decode_fails_at_3(ctx):
    """Decoder with a bug: it raises at step 3."""
    ctx.check_params(set())

    def decoder(spikes, window):
        if window.step == 3:
            raise ZeroDivisionError("division by zero")
        return MotorCommand.stop(window)

    return decoder
