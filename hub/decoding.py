"""Decoding schemes: the culture's spikes → the body's wheel speeds.

Each public function here is a scheme factory (see :mod:`hub.schemes`): called once with a
:class:`~hub.schemes.SchemeContext`, it validates ``ctx.params`` and returns the per-step
decoder ``decoder(spikes, window) -> MotorCommand`` (``window``: the step's
:class:`~hub.protocol.StepWindow`).

Both decoders look at the spikes of the last ``window_ms`` of culture time (the window ends at
the end of the latest batch, ``t1_s``), kept in a small ring of per-batch cumulative sums, so
each call costs a few numpy operations on that batch's spikes. Spikes on channels the culture
did not describe are ignored.

The culture is read with the body ↔ culture convention of :mod:`hub.coding`: forward is the
culture's +y, the robot's left is the culture's −x. A positive angular speed turns the robot
counter-clockwise (to its left); ``left = v − ω·b/2``, ``right = v + ω·b/2`` with ``b`` the
body's wheel base.

Schemes
-------
``center_of_activity``  the paper's decoder: speed from the CA's distance to the centre, turn
                        from its angle.
``two_population``      left and right halves of the culture, each population's firing rate
                        driving one wheel (crossed or not).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from hub.coding import CultureFrame
from hub.protocol import Description, MotorCommand, SpikeBatch, StepWindow
from hub.schemes import ConfigError, Decoder, SchemeContext, checked_by

WINDOW_MS = 50.0  # the paper's CA time scale
MIN_SPEED_MPS = 0.02
DEAD_ZONE_FRAC = 0.05  # CA within 5 % of the culture's radius counts as "at the centre"
TURN_GAIN_RAD_S_PER_RAD = 2.0
BASELINE_MPS = 0.0
RATE_GAIN_MPS_PER_HZ = 0.005


# --------------------------------------------------------------------------- helpers


class SpikeWindow:
    """Per-channel weights summed over the spikes of the last ``window_ms``.

    :meth:`add` takes a batch and returns the k sums of the weight rows of the spikes that
    fall in ``[t1 − window_ms, t1)`` (``t1`` the batch's end). A batch that starts before
    the previous one ended (a restarted culture) clears the window.

    Each batch is kept as its spikes' weight rows and their total; only the oldest batch,
    when the window starts inside it, is summed again. Channel ids index a table of weight
    rows directly (ids up to ``DENSE_CHANNEL_IDS``; larger ids are looked up by bisection);
    undescribed ids get a zero row, so their spikes count for nothing.

    Parameters
    ----------
    culture : Description
        The culture's description (its channel ids).
    weights : array of shape (n_channels, k)
        One row per described channel, in the description's order.
    window_ms : float
        The window's length in culture time (> 0).
    """

    DENSE_CHANNEL_IDS = 1 << 16

    def __init__(self, culture: Description, weights: np.ndarray, window_ms: float):
        weights = np.asarray(weights, dtype=np.float64)
        channel = culture.channel.astype(np.int64)
        self._dense = int(channel.max()) < self.DENSE_CHANNEL_IDS
        if self._dense:  # row c: the weights of channel id c; the last row, zeros, for the rest
            table = np.zeros((int(channel.max()) + 2, weights.shape[1]))
            table[channel] = weights
        else:  # rows in sorted id order, then a zero row
            order = np.argsort(channel, kind="stable")
            self._sorted_ids = channel[order]
            table = np.concatenate([weights[order], np.zeros((1, weights.shape[1]))])
        self._table = table
        self._zero_row = table.shape[0] - 1
        self.window_ms = window_ms
        self._ring: deque = deque()  # (t0_ms, t1_ms, t_ms, rows, total)

    def _weight_rows(self, channel: np.ndarray) -> np.ndarray:
        if self._dense:
            return self._table.take(channel, axis=0, mode="clip")
        pos = np.searchsorted(self._sorted_ids, channel)
        np.minimum(pos, self._zero_row - 1, out=pos)
        pos[self._sorted_ids[pos] != channel] = self._zero_row
        return self._table[pos]

    def add(self, spikes: SpikeBatch) -> tuple[np.ndarray, float]:
        """Take the next batch and sum the window that ends at its end.

        Returns
        -------
        sums : ndarray of shape (k,)
            The weight rows of the window's spikes, summed.
        covered_ms : float
            The culture time the window covers: less than ``window_ms`` until that much
            has been seen.
        """
        t0_ms, t1_ms = spikes.t0_s * 1e3, spikes.t1_s * 1e3
        ring = self._ring
        if ring and t0_ms < ring[-1][1] - 1e-6:
            ring.clear()
        rows = self._weight_rows(spikes.channel)
        ring.append((t0_ms, t1_ms, spikes.t_ms, rows, rows.sum(axis=0)))
        start_ms = t1_ms - self.window_ms
        while ring[0][1] <= start_ms:
            ring.popleft()
        b0, _, t_ms, rows, total = ring[0]
        if b0 < start_ms:  # the window starts inside the oldest batch
            total = rows[int(np.searchsorted(t_ms, start_ms - b0, side="left")) :].sum(axis=0)
        else:
            total = total.copy()
        for i in range(1, len(ring)):
            total += ring[i][4]
        return total, t1_ms - max(start_ms, b0)


def wheel_speeds(v_mps: float, omega_rad_s: float, body: Description) -> tuple[float, ...]:
    """``(left, right, v, ω)`` for a wanted ``v`` and ``ω``, within ±``max_wheel_mps``.

    Turning has priority: ``ω`` is first limited to what the wheels can do
    (``|ω|·b/2 ≤ max``), then ``v`` to what is left (``|v| + |ω|·b/2 ≤ max``), so the robot
    keeps the wanted turn rate, slows down if it must, and both wheels stay within limits.
    The returned ``v`` and ``ω`` are the ones the wheels give (m/s, rad/s).

    Parameters
    ----------
    v_mps : float
        Wanted forward speed.
    omega_rad_s : float
        Wanted turn rate, positive counter-clockwise.
    body : Description
        The body's description (``max_wheel_mps``, ``wheel_base_m``; a wheel base of 0
        allows no turn).
    """
    max_wheel = float(body.max_wheel_mps)
    half_base = float(body.wheel_base_m) / 2.0
    if half_base > 0:
        limit = max_wheel / half_base
        omega_rad_s = min(max(omega_rad_s, -limit), limit)
    else:
        omega_rad_s = 0.0
    spare = max_wheel - abs(omega_rad_s) * half_base
    v_mps = min(max(v_mps, -spare), spare)
    left = min(max(v_mps - omega_rad_s * half_base, -max_wheel), max_wheel)
    right = min(max(v_mps + omega_rad_s * half_base, -max_wheel), max_wheel)
    return left, right, v_mps, omega_rad_s


def _command(
    window: StepWindow, v_mps: float, omega_rad_s: float, body: Description
) -> MotorCommand:
    left, right, v, w = wheel_speeds(v_mps, omega_rad_s, body)
    return MotorCommand(**window.stamp, left_mps=left, right_mps=right, v_mps=v, omega_rad_s=w)


# --------------------------------------------------------------------------- schemes


def _coa_params(ctx: SchemeContext) -> dict:
    """:func:`center_of_activity`'s parameters, checked without the descriptions
    (``max_speed``, ``speed_gain`` None: the defaults, from the body)."""
    ctx.check_params(
        {
            "window_ms",
            "min_speed_mps",
            "max_speed_mps",
            "speed_gain_mps",
            "turn_gain_rad_s_per_rad",
            "dead_zone_frac",
            "centre_tau_s",
        }
    )
    min_speed = ctx.param("min_speed_mps", MIN_SPEED_MPS, ge=0.0)
    return dict(
        window_ms=ctx.param("window_ms", WINDOW_MS, gt=0.0),
        min_speed=min_speed,
        max_speed=ctx.param("max_speed_mps", None, ge=min_speed, bounds="min_speed_mps"),
        speed_gain=ctx.param("speed_gain_mps", None, ge=0.0),
        turn_gain=ctx.param("turn_gain_rad_s_per_rad", TURN_GAIN_RAD_S_PER_RAD),
        dead_zone=ctx.param("dead_zone_frac", DEAD_ZONE_FRAC, ge=0.0),
        centre_tau_s=ctx.param("centre_tau_s", 0.0, ge=0.0),
    )


@checked_by(_coa_params)
def center_of_activity(ctx: SchemeContext) -> Decoder:
    """The paper's decoder: the Center of Activity (CA) steers the robot.

    ``CA`` is the spike-weighted mean position of the channels over the last ``window_ms``
    (the paper's ``Σ FR_n · [x_n, y_n] / Σ FR_n``), taken relative to the culture's centre:
    distance ``d`` and angle ``θ`` (counter-clockwise from the culture's +y, so a CA on the
    culture's left half, −x, has θ > 0 and turns the robot left). Then:

    - no spike in the window, or ``d < dead_zone_frac · radius``: straight on at
      ``min_speed_mps`` (``ω = 0``);
    - otherwise ``v = clip(speed_gain_mps · d / radius, min_speed_mps, max_speed_mps)`` and
      ``ω = turn_gain_rad_s_per_rad · θ``;

    then wheels by :func:`wheel_speeds` (radius: see :class:`~hub.coding.CultureFrame`).

    The centre is the culture's geometric centre (the paper). With ``centre_tau_s > 0`` it is
    instead a running mean of the CA itself (exponential, time constant ``centre_tau_s``,
    starting at the geometric centre, updated at every step whose window has spikes), so a
    culture whose spontaneous activity sits off-centre does not steer the robot by that bias
    alone; only departures from its usual CA do (an extension, not in the paper).

    Parameters (``decoding.params``)
    --------------------------------
    window_ms : float, default 50
        Averaging window of the CA (the paper's time scale).
    min_speed_mps : float, default 0.02
        Speed at the centre, and the least speed elsewhere.
    max_speed_mps : float, default ``body.max_wheel_mps``
    speed_gain_mps : float, default ``body.max_wheel_mps``
        Speed for a CA one culture radius from the centre.
    turn_gain_rad_s_per_rad : float, default 2
        Angular speed per radian of CA angle.
    dead_zone_frac : float, default 0.05
        Radius of the "centre", as a fraction of the culture's radius.
    centre_tau_s : float, default 0
        0: the geometric centre; > 0: the CA's running mean over about this time.
    """
    p = _coa_params(ctx)
    body, culture = ctx.body, ctx.culture
    window_ms, min_speed, turn_gain = p["window_ms"], p["min_speed"], p["turn_gain"]
    dead_zone, centre_tau_s = p["dead_zone"], p["centre_tau_s"]
    max_wheel = float(body.max_wheel_mps)
    max_speed = p["max_speed"]
    if max_speed is None:  # the body's top speed, unless that is below the minimum
        max_speed = ctx.param("max_speed_mps", max_wheel, ge=min_speed)
    speed_gain = max_wheel if p["speed_gain"] is None else p["speed_gain"]
    # share of the way the running centre moves toward the CA at each step (0: fixed centre)
    follow = min(1.0, ctx.period_ms / 1e3 / centre_tau_s) if centre_tau_s > 0 else 0.0
    centre = [0.0, 0.0]  # relative to the geometric centre
    frame = CultureFrame.of(culture)
    rel = np.stack(
        [
            culture.x_um.astype(np.float64) - frame.centre_x_um,
            culture.y_um.astype(np.float64) - frame.centre_y_um,
            np.ones(culture.channel.size),
        ],
        axis=1,
    )
    spike_window = SpikeWindow(culture, rel, window_ms)
    dead_zone_um = dead_zone * frame.radius_um

    def decode(spikes: SpikeBatch, window: StepWindow) -> MotorCommand:
        (sx, sy, n), _ = spike_window.add(spikes)
        if n == 0:
            return _command(window, min_speed, 0.0, body)
        dx, dy = sx / n - centre[0], sy / n - centre[1]
        if follow:
            centre[0] += follow * dx
            centre[1] += follow * dy
        d_um = math.hypot(dx, dy)
        if d_um < dead_zone_um:
            return _command(window, min_speed, 0.0, body)
        theta = math.atan2(-dx, dy)  # CCW from +y: the culture's −x is the robot's left
        v = min(max(speed_gain * d_um / frame.radius_um, min_speed), max_speed)
        return _command(window, v, turn_gain * theta, body)

    return decode


def _listed_populations(ctx: SchemeContext) -> tuple[list, list] | None:
    """``left_channels`` and ``right_channels`` (both or neither), checked without the
    culture's description: lists of channel ids, none in both."""
    listed = [k for k in ("left_channels", "right_channels") if k in ctx.params]
    if not listed:
        return None
    if len(listed) != 2:
        missing = {"left_channels", "right_channels"} - set(listed)
        raise ConfigError(f"{ctx.section}.params.{missing.pop()} is needed with {listed[0]}")
    lists = []
    for key in ("left_channels", "right_channels"):
        chans = ctx.param(key, None, kind=list)
        if not chans or not all(isinstance(c, int) and not isinstance(c, bool) for c in chans):
            raise ConfigError(f"{ctx.section}.params.{key} must be a non-empty list of channel ids")
        lists.append(chans)
    if set(lists[0]) & set(lists[1]):
        raise ConfigError(f"{ctx.section}.params.left_channels and right_channels share channels")
    return lists[0], lists[1]


def _populations(ctx: SchemeContext) -> tuple[np.ndarray, np.ndarray]:
    """Boolean masks (over the culture's channels) of the left and right populations."""
    culture = ctx.culture
    listed = _listed_populations(ctx)
    if listed is not None:
        masks = []
        for key, chans in zip(("left_channels", "right_channels"), listed, strict=True):
            mask = np.isin(culture.channel, chans)
            unknown = set(chans) - set(culture.channel[mask].tolist())
            if unknown:
                raise ConfigError(
                    f"{ctx.section}.params.{key}: channel(s) {sorted(unknown)} not in the culture"
                )
            masks.append(mask)
        return masks[0], masks[1]
    frame = CultureFrame.of(culture)
    x = culture.x_um.astype(np.float64)
    left, right = x < frame.centre_x_um, x > frame.centre_x_um
    if not left.any() or not right.any():
        raise ConfigError("two_population: the culture has no channels on one side of its centre")
    return left, right


def _two_population_params(ctx: SchemeContext) -> dict:
    """:func:`two_population`'s parameters, checked without the descriptions."""
    ctx.check_params(
        {
            "window_ms",
            "gain_mps_per_hz",
            "baseline_mps",
            "crossed",
            "left_channels",
            "right_channels",
        }
    )
    _listed_populations(ctx)
    return dict(
        window_ms=ctx.param("window_ms", WINDOW_MS, gt=0.0),
        gain=ctx.param("gain_mps_per_hz", RATE_GAIN_MPS_PER_HZ),
        baseline=ctx.param("baseline_mps", BASELINE_MPS),
        crossed=ctx.param("crossed", True, kind=bool),
    )


@checked_by(_two_population_params)
def two_population(ctx: SchemeContext) -> Decoder:
    """Left and right halves of the culture drive the wheels with their firing rates.

    The left population is the channels with ``x`` left of the culture's centre (−x, the
    robot's left in the :mod:`hub.coding` convention) and the right population those right of
    it (channels on the centre line belong to neither), or the lists ``left_channels`` and
    ``right_channels``. ``rate_L``, ``rate_R`` are the mean firing rates per channel (spikes/s)
    of each population over the last ``window_ms``. With ``crossed = true`` (default)::

        left_mps  = baseline_mps + gain_mps_per_hz · rate_R
        right_mps = baseline_mps + gain_mps_per_hz · rate_L

    so activity on the culture's left turns the robot left (toward the side whose sensors are
    stimulated most: toward open space with :func:`hub.coding.somatotopic`); with
    ``crossed = false`` each population drives its own side's wheel (away from the most
    stimulated side: pair it with :func:`hub.coding.somatotopic_inverse`). Wheels are then
    limited by :func:`wheel_speeds`. Before any spike arrives both rates are 0.

    Parameters (``decoding.params``)
    --------------------------------
    window_ms : float, default 50
    gain_mps_per_hz : float, default 0.005
    baseline_mps : float, default 0
    crossed : bool, default true
    left_channels, right_channels : list of int, optional
    """
    p = _two_population_params(ctx)
    body = ctx.body
    window_ms, gain, baseline, crossed = p["window_ms"], p["gain"], p["baseline"], p["crossed"]
    left, right = _populations(ctx)
    # weights: 1/size of the population, so the sums are spikes per channel
    weights = np.stack([left / left.sum(), right / right.sum()], axis=1)
    spike_window = SpikeWindow(ctx.culture, weights, window_ms)
    half_base = float(body.wheel_base_m) / 2.0

    def decode(spikes: SpikeBatch, window: StepWindow) -> MotorCommand:
        (per_left, per_right), covered_ms = spike_window.add(spikes)
        to_hz = 1e3 / covered_ms if covered_ms > 0 else 0.0
        rate_left_hz, rate_right_hz = per_left * to_hz, per_right * to_hz
        if crossed:
            wheel_l = baseline + gain * rate_right_hz
            wheel_r = baseline + gain * rate_left_hz
        else:
            wheel_l = baseline + gain * rate_left_hz
            wheel_r = baseline + gain * rate_right_hz
        v = (wheel_l + wheel_r) / 2.0
        omega = (wheel_r - wheel_l) / (2.0 * half_base) if half_base > 0 else 0.0
        return _command(window, v, omega, body)

    return decode
