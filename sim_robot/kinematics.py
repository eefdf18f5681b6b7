"""Differential-drive kinematics: exact arc integration and wheel saturation."""

from __future__ import annotations

import math


def saturate(speed_mps: float, max_mps: float) -> float:
    """Clamp a wheel speed.

    Parameters
    ----------
    speed_mps, max_mps : float
        The speed and its limit (>= 0).

    Returns
    -------
    float
        ``speed_mps`` clamped to ``[-max_mps, max_mps]``.
    """
    return max(-max_mps, min(max_mps, speed_mps))


def wrap_angle(angle_rad: float) -> float:
    """The same angle in ``[-pi, pi]``.

    Parameters
    ----------
    angle_rad : float

    Returns
    -------
    float
        ``angle_rad`` plus a whole number of turns, in ``[-pi, pi]``.
    """
    return math.remainder(angle_rad, math.tau)


def arc_step(
    x_m: float,
    y_m: float,
    heading_rad: float,
    left_mps: float,
    right_mps: float,
    wheel_base_m: float,
    dt_s: float,
) -> tuple[float, float, float]:
    """Pose after driving the wheels at constant speeds for ``dt_s`` (exact, no Euler error).

    With ``v = (l + r) / 2`` and ``w = (r - l) / wheel_base`` the centre follows a circular
    arc (a line when ``w = 0``). The displacement is the arc's chord, of length
    ``v dt sinc(w dt / 2)``, along the mean heading ``heading + w dt / 2``; this form stays exact
    and well conditioned as ``w -> 0``.

    Parameters
    ----------
    x_m, y_m, heading_rad : float
        The pose before.
    left_mps, right_mps : float
        Wheel speeds (not saturated here).
    wheel_base_m : float
        Distance between the wheels.
    dt_s : float
        Duration.

    Returns
    -------
    (x_m, y_m, heading_rad)
        The pose after, the heading wrapped to ``[-pi, pi]``.
    """
    v = 0.5 * (left_mps + right_mps)
    dtheta = (right_mps - left_mps) / wheel_base_m * dt_s
    half = 0.5 * dtheta
    chord = v * dt_s * (math.sin(half) / half if half != 0.0 else 1.0)
    mid = heading_rad + half
    return (
        x_m + chord * math.cos(mid),
        y_m + chord * math.sin(mid),
        wrap_angle(heading_rad + dtheta),
    )
