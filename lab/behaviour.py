"""Behaviour metrics of a recorded run, for any body.

A record holds the body's poses (``SensorReading.pose``) and its ``Description``; the run's
config may name the world the body moved in. From the poses alone come the path metrics
(duration, distance, mean speed) of any body, real or simulated. When the world is known --
a ``sim_robot`` body's world file, its default, or a world given to a real body as
``body.params.world`` -- the arena and obstacle metrics of ``sim_robot.metrics`` are added,
with the robot's radius taken from the body's description when it gives one.

The world is loaded through ``sim_robot`` here, in the lab layer, never by the hub.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim_robot import World, load_world, trajectory_metrics, world_from_dict
from sim_robot.endpoint import DEFAULT_WORLD


def world_of(config: dict) -> World | None:
    """The world a recorded run's body moved in, or None when the run does not say.

    Parameters
    ----------
    config : dict
        The run's resolved config (``manifest["config"]``).

    Returns
    -------
    World or None
        ``body.params.world`` -- a world file path or the world's contents (a table) -- of
        any body; for a ``sim_robot`` body without one, the simulator's default world.
    """
    body = config.get("body") or {}
    world = (body.get("params") or {}).get("world")
    if world is None and body.get("kind") == "sim_robot":
        world = DEFAULT_WORLD
    if world is None:
        return None
    if isinstance(world, dict):
        return world_from_dict(world, source="the run's config")
    return load_world(Path(world))


def path_metrics(t_s: np.ndarray, poses: np.ndarray) -> dict:
    """Metrics of a trajectory that need no world.

    Parameters
    ----------
    t_s : float[N]
        Sample times (s), non-decreasing, N >= 1.
    poses : float[N, 3]
        ``(x_m, y_m, heading_rad)`` at each time.

    Returns
    -------
    dict
        ``duration_s``, ``distance_m`` (sum of straight segments between samples) and
        ``mean_speed_mps`` (distance / duration; 0 for a zero duration) -- the same
        definitions as ``sim_robot.metrics.trajectory_metrics``.
    """
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] != t.size or t.size == 0:
        raise ValueError(f"need N >= 1 times and (N, 3) poses, got {t.size} and {p.shape}")
    duration = float(t[-1] - t[0])
    distance = float(np.hypot(np.diff(p[:, 0]), np.diff(p[:, 1])).sum())
    return {
        "duration_s": duration,
        "distance_m": distance,
        "mean_speed_mps": distance / duration if duration > 0 else 0.0,
    }


def behaviour_metrics(
    t_s: np.ndarray, poses: np.ndarray, world: World | None = None, body=None
) -> dict:
    """Behaviour metrics of a trajectory: path metrics, plus arena metrics when ``world`` is known.

    Parameters
    ----------
    t_s : float[N]
        Sample times (s), non-decreasing.
    poses : float[N, 3]
        ``(x_m, y_m, heading_rad)`` at each time.
    world : World, optional
        The arena and obstacles; without it only :func:`path_metrics` are returned.
    body : hub.protocol.Description, optional
        The body's description; its ``radius_m``, when given, is the robot's disc for the
        obstacle and wall metrics (else the world's robot).

    Returns
    -------
    dict
        :func:`path_metrics`, and with a world everything of
        ``sim_robot.metrics.trajectory_metrics``.
    """
    metrics = path_metrics(t_s, poses)
    if world is not None:
        radius_m = getattr(body, "radius_m", None)
        radius_m = float(radius_m) if radius_m is not None and radius_m > 0 else None
        metrics.update(trajectory_metrics(world, t_s, poses, radius_m=radius_m))
    return metrics
