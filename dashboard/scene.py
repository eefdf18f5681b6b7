"""The scene: what does not change during a run — the arena and its obstacles, the robot's
geometry, the culture's channel layout, the loop's period — as one JSON-ready dict.

Built from the endpoints' :class:`~hub.protocol.Description` (what they say they are) and
the run's config (the hub's ``config`` control reply live, the manifest's ``config`` in a
replay). The world, when the config names one, is read by the lab layer
(:func:`lab.behaviour.world_of`, imported with this module; a first read also loads the
geometry kernels, seconds of CPU on a slow machine: the observer reads it before it
subscribes to the hub's views, which a hub told to wait for its dashboard waits for); a body in a
world not known here (a real robot without ``body.params.world``) is drawn in an arena
fitted to its trail.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from hub.protocol import Description
from lab.behaviour import world_of

log = logging.getLogger(__name__)


def build_scene(descriptions: dict[str, Description], config: dict | None, world) -> dict:
    """The scene of a run.

    Parameters
    ----------
    descriptions : dict
        Role -> the endpoint's description (either may be missing).
    config : dict or None
        The run's config as a plain dict (``ExperimentConfig.to_dict()``).
    world : sim_robot.World or None
        The run's world (:func:`world_for` of ``config``), None if not known.

    Returns
    -------
    dict
        ``name``, ``mode``, ``period_ms``, ``n_steps``, ``arena`` (or None), ``obstacles``,
        ``body`` (or None), ``culture`` (or None).
    """
    config = config or {}
    loop = config.get("loop", {})
    experiment = config.get("experiment", {})
    period_ms = loop.get("period_ms")
    duration_s = experiment.get("duration_s")
    scene = {
        "name": experiment.get("name", ""),
        "mode": loop.get("mode", ""),
        "period_ms": period_ms,
        "n_steps": round(duration_s * 1e3 / period_ms) if period_ms and duration_s else None,
        "arena": None,
        "obstacles": [],
        "body": None,
        "culture": None,
    }
    if world is not None:
        scene["arena"] = _arena(world.arena)
        scene["obstacles"] = [_obstacle(ob) for ob in world.obstacles]
    body = descriptions.get("body")
    if body is not None:
        scene["body"] = _body(body, world)
    culture = descriptions.get("culture")
    if culture is not None:
        scene["culture"] = _culture(culture)
    return scene


def world_for(config: dict | None):
    """The world of the run's body, or None (not named, or not readable here)."""
    if not config or not config.get("body"):
        return None
    try:
        return world_of(config)
    except Exception as exc:  # a world file of another machine: the page does without it
        log.warning("the run's world is not drawn: %s", exc)
        return None


def _arena(arena) -> dict:
    if arena.shape == "circle":
        return {"shape": "circle", "radius_m": float(arena.radius_m)}
    return {
        "shape": "rectangle",
        "width_m": float(arena.width_m),
        "height_m": float(arena.height_m),
    }


def _obstacle(ob) -> dict:
    if ob.is_circle:
        return {
            "shape": "circle",
            "center_m": [float(v) for v in ob.center_m],
            "radius_m": float(ob.radius_m),
        }
    return {"shape": "polygon", "vertices_m": np.round(ob.vertices_m, 6).tolist()}


def _body(desc: Description, world) -> dict:
    angles = np.asarray(desc.sensor_angles_rad, np.float64)
    offsets = None
    if world is not None and world.body.n_sensors == angles.size:
        offsets = np.round(world.body.sensor_offsets_m, 6).tolist()
    return {
        "id": desc.id,
        "kind": desc.kind,
        "radius_m": desc.radius_m,
        "wheel_base_m": desc.wheel_base_m,
        "max_range_m": desc.max_range_m,
        "max_wheel_mps": desc.max_wheel_mps,
        "sensor_angles_rad": np.round(angles, 6).tolist(),
        # each range finder's place on the body (x forward, y left); else on its rim
        "sensor_offsets_m": offsets
        or [
            [round(desc.radius_m * math.cos(a), 6), round(desc.radius_m * math.sin(a), 6)]
            for a in angles.tolist()
        ],
    }


def _culture(desc: Description) -> dict:
    return {
        "id": desc.id,
        "kind": desc.kind,
        "channel": desc.channel.tolist(),
        "x_um": np.round(desc.x_um.astype(np.float64), 2).tolist(),
        "y_um": np.round(desc.y_um.astype(np.float64), 2).tolist(),
        "cell_type": None if desc.cell_type is None else desc.cell_type.tolist(),
    }
