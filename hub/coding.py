"""Coding schemes: the body's range readings → the culture's stimulation.

Each public function here is a scheme factory (see :mod:`hub.schemes`): called once with a
:class:`~hub.schemes.SchemeContext`, it validates ``ctx.params`` and returns the per-step
coder ``coder(sensors, window) -> Stimulation`` (``window``: the step's
:class:`~hub.protocol.StepWindow`).

Body ↔ culture convention (shared with :mod:`hub.decoding`)
-----------------------------------------------------------
The culture is seen from above as a map of the body: the robot's **forward** is the culture's
**+y** and the robot's **left** is the culture's **−x**. A body angle ``a`` (radians,
counter-clockwise from forward, as the body's ``sensor_angles_rad``) is the culture direction
``(−sin a, cos a)`` from the culture's centre. The centre is the middle of the bounding box of
the channels' positions and the culture's radius is half the larger side of that box
(:class:`CultureFrame`).

Schemes
-------
``somatotopic``          one site per sensor at the sensor's angle; amplitude ``A · d_s``
                         (farther obstacle → stronger), the paper's scheme (section 3.3).
``somatotopic_inverse``  same sites; amplitude ``A · (max_range − d_s)`` (nearer → stronger).
``rate``                 same sites; fixed amplitude, pulse frequency rising linearly from
                         ``min_rate_hz`` (nothing seen) to ``max_rate_hz`` (obstacle touching).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hub.protocol import Description, SensorReading, StepWindow, Stimulation
from hub.schemes import Coder, ConfigError, SchemeContext, checked_by

# One place for the defaults shared by the schemes.
FULL_SCALE_UA = 100.0  # amplitude at full range (amplitude codes), and the rate code's amplitude
MIN_AMPLITUDE_UA = 20.0  # below this no pulse is sent (a 10 ms pulse under ~25 µA is sub-threshold)
MAX_AMPLITUDE_UA = 150.0  # safety clamp
WIDTH_MS = 10.0  # the paper's pulse width
SITE_RADIUS_FRAC = 0.6  # sites on a circle of 0.6 × the culture's radius
SITES_PER_SENSOR = 1
MIN_RATE_HZ = 0.0
MAX_RATE_HZ = 20.0

_SITE_PARAMS = {"site_radius_frac", "sites_per_sensor", "channels", "excitatory_only"}
_PULSE_PARAMS = {"width_ms", "max_amplitude_ua"}


# --------------------------------------------------------------------------- geometry


@dataclass(frozen=True)
class CultureFrame:
    """The culture's centre and radius (µm), from its channel positions.

    ``centre`` is the middle of the bounding box of ``x_um``, ``y_um``; ``radius_um`` is half
    the larger side of that box (at least 1 µm, so a one-channel culture still has a scale).
    """

    centre_x_um: float
    centre_y_um: float
    radius_um: float

    @classmethod
    def of(cls, culture: Description) -> CultureFrame:
        """The frame of ``culture``'s channel positions.

        Raises
        ------
        ConfigError
            The description lists no channels.
        """
        x = np.asarray(culture.x_um, dtype=np.float64)
        y = np.asarray(culture.y_um, dtype=np.float64)
        if x.size == 0:
            raise ConfigError("the culture's description lists no channels")
        half = max(x.max() - x.min(), y.max() - y.min()) / 2.0
        return cls(
            float((x.min() + x.max()) / 2.0), float((y.min() + y.max()) / 2.0), max(half, 1.0)
        )

    def point_at(self, angle_rad: float, distance_um: float) -> tuple[float, float]:
        """The culture point ``(x_um, y_um)`` at a body angle and a distance from the centre.

        Parameters
        ----------
        angle_rad : float
            Body angle, counter-clockwise from forward.
        distance_um : float
            Distance from the centre.
        """
        return (
            self.centre_x_um - distance_um * math.sin(angle_rad),
            self.centre_y_um + distance_um * math.cos(angle_rad),
        )


def site_params(ctx: SchemeContext) -> dict:
    """The site-placement parameters, checked without the endpoints' descriptions.

    Returns ``channels`` (one list of channel ids per sensor, or None), ``radius_frac``,
    ``per_sensor`` and ``excitatory_only``. A channel listed for two sensors is refused here;
    the count of sensors and the culture's channels are checked by :func:`stimulation_sites`.
    """
    key = f"{ctx.section}.params.channels"
    channels = None
    if "channels" in ctx.params:
        channels, seen = [], set()
        for s, entry in enumerate(ctx.param("channels", None, kind=list)):
            chans = entry if isinstance(entry, list) else [entry]
            if not chans or not all(isinstance(c, int) and not isinstance(c, bool) for c in chans):
                raise ConfigError(
                    f"{key}[{s}] must be a channel id or a non-empty list of them, got {entry!r}"
                )
            for c in chans:
                if c in seen:
                    raise ConfigError(f"{key}[{s}]: channel {c} is listed for two sensors")
                seen.add(c)
            channels.append(chans)
    return {
        "channels": channels,
        "radius_frac": ctx.param("site_radius_frac", SITE_RADIUS_FRAC, ge=0.0, le=1.0),
        "per_sensor": ctx.param("sites_per_sensor", SITES_PER_SENSOR, kind=int, ge=1),
        "excitatory_only": ctx.param("excitatory_only", True, kind=bool),
    }


def stimulation_sites(ctx: SchemeContext) -> list[np.ndarray]:
    """The channels stimulated for each sensor, in the body's sensor order.

    Either listed by hand (``params.channels``: one channel or one list of channels per
    sensor), or placed somatotopically: sensor ``s`` at body angle ``a_s`` gets the
    ``sites_per_sensor`` channels nearest to the culture point at angle ``a_s`` and distance
    ``site_radius_frac × radius`` from the centre (see :class:`CultureFrame`). With
    ``excitatory_only`` (default true) and a culture that reports ``cell_type``, only
    excitatory channels are candidates. A channel is never given to two sensors: each sensor,
    in order, takes the nearest channels not already taken. The parameters are checked by
    :func:`site_params`; here, what needs the descriptions (one entry per sensor, channels
    the culture has, enough channels for the sites).
    """
    body, culture = ctx.body, ctx.culture
    n_sensors = body.n_sensors
    p = site_params(ctx)
    if p["channels"] is not None:
        key = f"{ctx.section}.params.channels"
        listed = p["channels"]
        if len(listed) != n_sensors:
            raise ConfigError(
                f"{key} must list one entry per sensor ({n_sensors}), got {len(listed)}"
            )
        known = set(culture.channel.tolist())
        for s, chans in enumerate(listed):
            for c in chans:
                if c not in known:
                    raise ConfigError(f"{key}[{s}]: channel {c} is not one of the culture's")
        return [np.asarray(chans, dtype=np.uint32) for chans in listed]

    radius_frac, per_sensor = p["radius_frac"], p["per_sensor"]
    candidates = np.ones(culture.channel.size, dtype=bool)
    if p["excitatory_only"] and culture.cell_type is not None:
        candidates &= culture.cell_type == 0
    if per_sensor * n_sensors > int(candidates.sum()):
        raise ConfigError(
            f"{ctx.section}.params.sites_per_sensor: {per_sensor} sites for each of "
            f"{n_sensors} sensors needs {per_sensor * n_sensors} channels, the culture offers "
            f"{int(candidates.sum())}"
        )
    frame = CultureFrame.of(culture)
    x = culture.x_um.astype(np.float64)
    y = culture.y_um.astype(np.float64)
    sites = []
    for angle in body.sensor_angles_rad.astype(np.float64):
        px, py = frame.point_at(angle, radius_frac * frame.radius_um)
        d2 = np.where(candidates, (x - px) ** 2 + (y - py) ** 2, np.inf)
        # stable sort: ties go to the lower index, so placement is deterministic
        nearest = np.argsort(d2, kind="stable")[:per_sensor]
        candidates[nearest] = False
        sites.append(culture.channel[nearest].astype(np.uint32))
    return sites


# --------------------------------------------------------------------------- pulses


def _ranges(sensors: SensorReading, n_sensors: int) -> list[float]:
    """The reading's ranges as Python floats (a handful: plain Python beats numpy here)."""
    ranges = sensors.ranges_m
    if ranges.size != n_sensors:
        raise ValueError(
            f"sensor reading of step {sensors.step} has {ranges.size} ranges, "
            f"the body described {n_sensors}"
        )
    return ranges.tolist()


def _stimulation(window, channel, amplitude_ua, width_ms, onset_ms) -> Stimulation:
    """A Stimulation from Python lists, built directly in the wire's dtypes."""
    return Stimulation(
        **window.stamp,
        channel=np.array(channel, dtype=np.uint32),
        amplitude_ua=np.array(amplitude_ua, dtype=np.float32),
        width_ms=np.full(len(channel), width_ms, dtype=np.float32),
        onset_ms=np.array(onset_ms, dtype=np.float32),
    )


def _last_onset_ms(period_ms: float) -> float:
    """The latest onset inside a step, as the wire's float32 can say it (strictly < period)."""
    return float(np.nextafter(np.float32(period_ms), np.float32(0.0)))


def _pulse_params(ctx: SchemeContext) -> tuple[float, float]:
    width_ms = ctx.param("width_ms", WIDTH_MS, gt=0.0)
    max_amplitude_ua = ctx.param("max_amplitude_ua", MAX_AMPLITUDE_UA, gt=0.0)
    return width_ms, max_amplitude_ua


def _amplitude_params(ctx: SchemeContext) -> dict:
    """The amplitude codes' parameters, checked without the descriptions (``gain`` None:
    the default, from the body's range)."""
    ctx.check_params(
        _SITE_PARAMS | _PULSE_PARAMS | {"gain_ua_per_m", "min_amplitude_ua", "pulse_period_ms"}
    )
    gain = ctx.param("gain_ua_per_m", None, ge=0.0)
    width_ms, max_ua = _pulse_params(ctx)
    min_ua = ctx.param("min_amplitude_ua", MIN_AMPLITUDE_UA, ge=0.0)
    if min_ua > max_ua:
        raise ConfigError(
            f"{ctx.section}.params.min_amplitude_ua must be <= max_amplitude_ua ({max_ua}), "
            f"got {min_ua}"
        )
    given = "pulse_period_ms" in ctx.params
    pulse_period_ms = ctx.param("pulse_period_ms", float(ctx.period_ms), gt=0.0)
    if pulse_period_ms < width_ms:
        source = "" if given else " (its default: loop.period_ms)"
        raise ConfigError(
            f"{ctx.section}.params.pulse_period_ms{source} must be >= width_ms ({width_ms}) "
            f"so that a site's pulses do not overlap, got {pulse_period_ms}: set "
            f"{ctx.section}.params.width_ms to at most {pulse_period_ms:g}, or "
            f"pulse_period_ms to at least {width_ms:g}"
        )
    site_params(ctx)
    return dict(
        gain=gain, width_ms=width_ms, max_ua=max_ua, min_ua=min_ua, pulse_period_ms=pulse_period_ms
    )


def _amplitude_code(ctx: SchemeContext, *, inverse: bool) -> Coder:
    p = _amplitude_params(ctx)
    body = ctx.body
    max_range_m = float(body.max_range_m)
    if not max_range_m > 0:
        raise ConfigError(f"the body's max_range_m must be > 0, got {max_range_m}")
    gain = FULL_SCALE_UA / max_range_m if p["gain"] is None else p["gain"]
    width_ms, max_ua, min_ua = p["width_ms"], p["max_ua"], p["min_ua"]
    period_ms = float(ctx.period_ms)
    pulse_period_ms = p["pulse_period_ms"]
    sites = [site.tolist() for site in stimulation_sites(ctx)]
    n_sensors = body.n_sensors
    last_onset_ms = _last_onset_ms(period_ms)

    def code(sensors: SensorReading, window: StepWindow) -> Stimulation:
        t0_ms = window.t0_s * 1e3
        # pulse times m·P inside [t0, t0 + T): the same grid for every site
        m0 = math.ceil(t0_ms / pulse_period_ms - 1e-9)
        m1 = math.ceil((t0_ms + period_ms) / pulse_period_ms - 1e-9)
        if m1 <= m0:
            return Stimulation.none(window)
        channel, amplitude = [], []
        for chans, d in zip(sites, _ranges(sensors, n_sensors), strict=True):
            d = min(max(d, 0.0), max_range_m)
            amp = min(gain * ((max_range_m - d) if inverse else d), max_ua)
            if amp > 0.0 and amp >= min_ua:
                channel += chans
                amplitude += [amp] * len(chans)
        if not channel:
            return Stimulation.none(window)
        onsets = [min(max(m * pulse_period_ms - t0_ms, 0.0), last_onset_ms) for m in range(m0, m1)]
        n_on = len(channel)
        return _stimulation(
            window,
            channel * len(onsets),
            amplitude * len(onsets),
            width_ms,
            [t for t in onsets for _ in range(n_on)],
        )

    return code


@checked_by(_amplitude_params)
def somatotopic(ctx: SchemeContext) -> Coder:
    """The paper's coding: one site per sensor, amplitude ``A · d_s`` (farther → stronger).

    Parameters (``coding.params``)
    -------------------------------
    gain_ua_per_m : float, default ``100 / body.max_range_m``
        ``A``: µA per metre of range (so nothing seen gives 100 µA by default).
    min_amplitude_ua : float, default 20
        Pulses weaker than this are not sent.
    max_amplitude_ua : float, default 150
        Safety clamp on every pulse.
    width_ms : float, default 10
        Pulse width; a pulse may run past its step into the next.
    pulse_period_ms : float, default the loop period
        Pulses fall at ``0, P, 2P, …`` ms of run time (every step by default); must be
        ``>= width_ms``.
    site_radius_frac, sites_per_sensor, excitatory_only, channels
        Site placement, see :func:`stimulation_sites`.
    """
    return _amplitude_code(ctx, inverse=False)


@checked_by(_amplitude_params)
def somatotopic_inverse(ctx: SchemeContext) -> Coder:
    """Somatotopic sites, amplitude ``A · (max_range − d_s)``: nearer obstacle → stronger.

    The usual choice with real infrared sensors. Same parameters as :func:`somatotopic`
    (``gain_ua_per_m`` defaults to ``100 / max_range_m``, so an obstacle touching the sensor
    gives 100 µA and nothing in range gives no pulse).
    """
    return _amplitude_code(ctx, inverse=True)


def _rate_params(ctx: SchemeContext) -> dict:
    """The rate code's parameters, checked without the descriptions."""
    ctx.check_params(_SITE_PARAMS | _PULSE_PARAMS | {"min_rate_hz", "max_rate_hz", "amplitude_ua"})
    width_ms, max_ua = _pulse_params(ctx)
    amplitude_ua = min(ctx.param("amplitude_ua", FULL_SCALE_UA, gt=0.0), max_ua)
    min_hz = ctx.param("min_rate_hz", MIN_RATE_HZ, ge=0.0)
    max_hz = ctx.param(
        "max_rate_hz", MAX_RATE_HZ, ge=min_hz, le=1000.0 / width_ms,
        bounds=f"at least min_rate_hz, at most one pulse a width_ms of {width_ms:g} ms",
    )  # fmt: skip
    site_params(ctx)
    return dict(width_ms=width_ms, amplitude_ua=amplitude_ua, min_hz=min_hz, max_hz=max_hz)


@checked_by(_rate_params)
def rate(ctx: SchemeContext) -> Coder:
    """Somatotopic sites, distance coded as pulse frequency (nearer → more pulses per second).

    ``f_s = min_rate_hz + (max_rate_hz − min_rate_hz) · (1 − d_s / max_range_m)``. Each site
    keeps a phase in ``[0, 1]`` that advances by ``f_s · T`` over a step; a pulse is sent each
    time the phase reaches a whole number, at the exact time inside the step, so the number of
    pulses over any stretch of constant ``f_s`` is ``f_s × time`` to within one pulse. A site
    starts with its phase at 1: its first pulse falls at the start of the first step in which
    its rate is above zero.

    Parameters (``coding.params``)
    -------------------------------
    min_rate_hz : float, default 0
        Frequency when nothing is in range.
    max_rate_hz : float, default 20
        Frequency for an obstacle touching the sensor; at most ``1000 / width_ms``.
    amplitude_ua : float, default 100
        Amplitude of every pulse (clamped to ``max_amplitude_ua``).
    width_ms, max_amplitude_ua, site_radius_frac, sites_per_sensor, excitatory_only, channels
        As in :func:`somatotopic`.
    """
    p = _rate_params(ctx)
    body = ctx.body
    max_range_m = float(body.max_range_m)
    if not max_range_m > 0:
        raise ConfigError(f"the body's max_range_m must be > 0, got {max_range_m}")
    width_ms, amplitude_ua = p["width_ms"], p["amplitude_ua"]
    min_hz, max_hz = p["min_hz"], p["max_hz"]
    sites = [site.tolist() for site in stimulation_sites(ctx)]
    n_sensors = body.n_sensors
    period_ms = float(ctx.period_ms)
    period_s = period_ms / 1e3
    last_onset_ms = _last_onset_ms(period_ms)
    span_hz = max_hz - min_hz
    phase = [1.0] * n_sensors  # one phase per sensor: a sensor's sites pulse together

    def code(sensors: SensorReading, window: StepWindow) -> Stimulation:
        channel, onset = [], []
        for s, d in enumerate(_ranges(sensors, n_sensors)):
            d = min(max(d, 0.0), max_range_m)
            hz = min_hz + span_hz * (1.0 - d / max_range_m)
            end = phase[s] + hz * period_s
            # pulses where the phase crosses j = 1, 2, … with j < end (a crossing at the very
            # end, within rounding, is left to the start of the next step)
            n = max(math.ceil(end - 1e-9) - 1, 0)
            if n:
                chans = sites[s]
                for j in range(1, n + 1):
                    t_ms = min(max((j - phase[s]) / hz * 1e3, 0.0), last_onset_ms)
                    channel += chans
                    onset += [t_ms] * len(chans)
            phase[s] = end - n
        if not channel:
            return Stimulation.none(window)
        return _stimulation(window, channel, [amplitude_ua] * len(channel), width_ms, onset)

    return code
