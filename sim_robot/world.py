"""Worlds: the arena, its obstacles, the robot body and start pose, and the physics options.

A :class:`World` is plain data (dataclasses and numpy arrays), validated on construction, so
pictures and trajectory metrics can use it without a simulator. World files are TOML
(``configs/worlds/``, format in ``docs/sim_robot.md``), read through :mod:`settings` (the
project's one loader: ``extends`` relative to the file, tables merge, arrays such as
``[[obstacles]]`` replace); :func:`load_world` reads one and :func:`world_from_dict` builds
from the same structure in Python.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import settings

from . import bodies
from .bodies import Body
from .errors import WorldError
from .geometry import (
    KIND_CIRCLE,
    KIND_POLYGON,
    WALL_CIRCLE,
    WALL_RECTANGLE,
    Geometry,
    disc_state,
    polygon_self_intersection,
    polygon_signed_area,
)

# The world of the paper's closed loop: the default world of a simulated body.
DEFAULT_WORLD_FILE = Path(__file__).resolve().parents[1] / "configs" / "worlds" / "paper.toml"

# The tables and values of a world file.
WORLD_KEYS = ("name", "description", "arena", "physics", "robot", "sensors", "obstacles")
PHYSICS_MODES = ("pass", "solid")
ARENA_SHAPES = ("circle", "rectangle")
OBSTACLE_SHAPES = ("circle", "square", "rectangle", "triangle", "polygon")


@dataclass(frozen=True)
class ArenaShape:
    """The arena, centred on the origin: a circle of ``radius_m`` or a ``width_m`` x
    ``height_m`` rectangle."""

    shape: str
    radius_m: float = 0.0
    width_m: float = 0.0
    height_m: float = 0.0

    def bounds_m(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the arena."""
        if self.shape == "circle":
            r = self.radius_m
            return -r, r, -r, r
        return -self.width_m / 2, self.width_m / 2, -self.height_m / 2, self.height_m / 2


@dataclass(frozen=True, eq=False)
class Obstacle:
    """One obstacle in world coordinates.

    ``shape`` is what the file asked for (circle, square, rectangle, triangle, polygon);
    circles carry ``center_m`` and ``radius_m``, every other shape its counter-clockwise
    ``vertices_m`` (float64[k, 2]) after placement and rotation.
    """

    shape: str
    center_m: tuple[float, float]
    radius_m: float = 0.0
    vertices_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    @property
    def is_circle(self) -> bool:
        """Whether this is a circle (``center_m``, ``radius_m``) rather than a polygon."""
        return self.shape == "circle"


@dataclass(frozen=True, eq=False)
class World:
    """A validated world.

    Attributes
    ----------
    name : str
    arena : ArenaShape
    obstacles : tuple of Obstacle
    body : Body
    start_pose : (x_m, y_m, heading_rad)
    obstacles_solid, walls_solid : bool
        False: pass-through (seen by the sensors, not stopping the robot; the paper's choice);
        True: the robot collides and slides.
    noise_sd_m : float
        Standard deviation of Gaussian range noise (0 = noise-free, the default).
    """

    name: str
    arena: ArenaShape
    obstacles: tuple[Obstacle, ...]
    body: Body
    start_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    obstacles_solid: bool = False
    walls_solid: bool = False
    noise_sd_m: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "obstacles", tuple(self.obstacles))
        object.__setattr__(self, "start_pose", tuple(float(v) for v in self.start_pose))
        object.__setattr__(self, "geometry", _flatten(self))
        _validate(self)

    geometry: Geometry = field(init=False, repr=False)


# ---------------------------------------------------------------- flattening and validation


def disc_flags(
    world: World, x_m: np.ndarray, y_m: np.ndarray, radius_m: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where a robot disc at each of n positions is, relative to obstacles and walls.

    Parameters
    ----------
    world : World
    x_m, y_m : array_like
        The disc's centres (m); flattened, same size n.
    radius_m : float, optional
        The disc (m); default the world's robot.

    Returns
    -------
    overlap : bool[n, n_obstacles]
        The disc touches or overlaps obstacle j.
    outside : bool[n]
        The centre is outside the arena.
    touch : bool[n]
        The disc touches or crosses the wall.
    """
    g = world.geometry
    x = np.ascontiguousarray(x_m, dtype=np.float64).reshape(-1)
    y = np.ascontiguousarray(y_m, dtype=np.float64).reshape(-1)
    overlap = np.zeros((x.size, g.n_obstacles), dtype=np.bool_)
    outside = np.zeros(x.size, dtype=np.bool_)
    touch = np.zeros(x.size, dtype=np.bool_)
    radius = world.body.radius_m if radius_m is None else radius_m
    disc_state(
        x, y, radius, g.obs_kind, g.obs_circle, g.poly_vertex, g.obs_start,
        g.wall_kind, g.wall_param, overlap, outside, touch,
    )  # fmt: skip
    return overlap, outside, touch


def _flatten(world: World) -> Geometry:
    n = len(world.obstacles)
    kind = np.zeros(n, dtype=np.int8)
    circ = np.zeros((n, 3), dtype=np.float64)
    start = np.zeros(n + 1, dtype=np.int64)
    verts = []
    for j, ob in enumerate(world.obstacles):
        if ob.is_circle:
            kind[j] = KIND_CIRCLE
            circ[j] = (ob.center_m[0], ob.center_m[1], ob.radius_m)
            start[j + 1] = start[j]
        else:
            kind[j] = KIND_POLYGON
            verts.append(np.asarray(ob.vertices_m, dtype=np.float64))
            start[j + 1] = start[j] + len(ob.vertices_m)
    poly = np.concatenate(verts) if verts else np.zeros((0, 2))
    a = world.arena
    if a.shape == "circle":
        wall_kind, wall_param = WALL_CIRCLE, np.array([a.radius_m, 0.0])
    else:
        wall_kind, wall_param = WALL_RECTANGLE, np.array([a.width_m / 2, a.height_m / 2])
    return Geometry(kind, circ, np.ascontiguousarray(poly), start, wall_kind, wall_param)


def _validate(world: World) -> None:
    a = world.arena
    if a.shape not in ARENA_SHAPES:
        raise WorldError(f"arena.shape must be one of {ARENA_SHAPES}, got {a.shape!r}")
    keys = ("radius_m",) if a.shape == "circle" else ("width_m", "height_m")
    for key in keys:
        _positive(f"arena.{key}", getattr(a, key))
    if not (math.isfinite(world.noise_sd_m) and world.noise_sd_m >= 0):
        raise WorldError(f"sensors.noise_sd_m must be >= 0, got {world.noise_sd_m!r}")
    if not all(math.isfinite(v) for v in world.start_pose):
        raise WorldError(f"robot.start must be finite, got {world.start_pose}")
    for j, ob in enumerate(world.obstacles):
        where = f"obstacles[{j}] ({ob.shape})"
        if ob.is_circle:
            _positive(f"obstacles[{j}].radius_m", ob.radius_m)
            cx, cy = ob.center_m
            r = ob.radius_m
            # the extreme points decide containment in an axis-aligned rectangle exactly
            pts = np.array([(cx - r, cy), (cx + r, cy), (cx, cy - r), (cx, cy + r)])
            if a.shape == "circle":  # exact test for a disc in a disc
                beyond = math.hypot(cx, cy) + ob.radius_m - a.radius_m
                if beyond > 1e-12:
                    raise WorldError(
                        f"{where} lies partly outside the arena: it reaches {beyond:.4g} m "
                        f"beyond arena.radius_m {a.radius_m}"
                    )
                continue
        else:
            pts = np.asarray(ob.vertices_m, dtype=np.float64)
            if pts.ndim != 2 or pts.shape[0] < 3 or pts.shape[1] != 2:
                raise WorldError(
                    f"obstacles[{j}].vertices_m must list at least 3 [x, y] points, "
                    f"got shape {pts.shape}"
                )
            if not np.all(np.isfinite(pts)):
                raise WorldError(f"obstacles[{j}].vertices_m must be finite")
            crossing = polygon_self_intersection(pts)
            if crossing is not None:
                raise WorldError(
                    f"obstacles[{j}].vertices_m is a self-intersecting polygon: edges "
                    f"{crossing[0]} and {crossing[1]} cross or touch"
                )
            if abs(polygon_signed_area(pts)) < 1e-12:
                raise WorldError(f"{where} has zero area (vertices are collinear or repeated)")
        _inside_arena(where, pts, a)
    # robot start: inside the arena and clear of every obstacle
    x, y, _ = world.start_pose
    r = world.body.radius_m
    overlap, outside, touch = disc_flags(world, np.array([x]), np.array([y]))
    hit = np.flatnonzero(overlap[0])
    if hit.size:
        j = int(hit[0])
        raise WorldError(
            f"robot.start ({x}, {y}) puts the robot (radius {r} m) inside or touching "
            f"obstacles[{j}] ({world.obstacles[j].shape})"
        )
    if outside[0] or touch[0]:
        raise WorldError(
            f"robot.start ({x}, {y}) puts the robot (radius {r} m) outside or across the arena wall"
        )


def _positive(key: str, value) -> None:
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
    if not (ok and math.isfinite(value) and value > 0):
        raise WorldError(f"{key} must be a finite number > 0, got {value!r}")


def _inside_arena(where: str, pts: np.ndarray, a: ArenaShape) -> None:
    if a.shape == "circle":
        excess = np.hypot(pts[:, 0], pts[:, 1]) - a.radius_m
        limit = f"arena.radius_m {a.radius_m}"
    else:
        excess = np.maximum(np.abs(pts[:, 0]) - a.width_m / 2, np.abs(pts[:, 1]) - a.height_m / 2)
        limit = f"the {a.width_m} x {a.height_m} m arena"
    k = int(np.argmax(excess))
    if excess[k] > 1e-12:
        raise WorldError(
            f"{where} lies partly outside the arena: point ({pts[k, 0]:.4g}, {pts[k, 1]:.4g}) "
            f"is {excess[k]:.4g} m beyond {limit}"
        )


# ---------------------------------------------------------------- reading world files


def load_world(path: str | Path, overrides: Sequence[str] = ()) -> World:
    """Read and validate a TOML world file (see ``docs/sim_robot.md``).

    Parameters
    ----------
    path : str or Path
        The world file.
    overrides : sequence of str
        ``dotted.key=value`` items applied after the file (``arena.radius_m=0.8``).

    Raises
    ------
    WorldError
        The file or the world is invalid (the message names the key).
    ConfigError
        An override is malformed.
    """
    data = settings.apply_overrides(read_world_data(path), overrides)
    return world_from_dict(data, source=str(path))


def read_world_data(path: str | Path) -> dict:
    """The plain contents of a world file, its ``extends`` applied, not yet validated.

    Raises
    ------
    WorldError
        The file is missing, not TOML, empty, or its ``extends`` chain is broken.
    """
    try:
        return settings.load(path, "world file")
    except WorldError:
        raise
    except settings.ConfigError as exc:
        raise WorldError(str(exc)) from None


def world_from_dict(data: dict, source: str = "<dict>") -> World:
    """Build a :class:`World` from the world-file structure (a nested dict).

    Parameters
    ----------
    data : dict
        A world file's contents (an ``extends`` key is ignored).
    source : str
        Where ``data`` came from: named in errors; its stem is the default world name.

    Raises
    ------
    WorldError
        The world is invalid (the message names the key).
    """
    data = dict(data)
    data.pop("extends", None)
    _known("", data, WORLD_KEYS)
    arena = _arena(_table(data, "arena"))
    physics = _table(data, "physics", required=False)
    _known("physics", physics, ("obstacles", "walls"))
    solid = {}
    for key in ("obstacles", "walls"):
        mode = physics.get(key, "pass")
        if mode not in PHYSICS_MODES:
            raise WorldError(f"physics.{key} must be one of {PHYSICS_MODES}, got {mode!r}")
        solid[key] = mode == "solid"
    body, start_pose = _robot(_table(data, "robot"))
    sensors = _table(data, "sensors", required=False)
    _known("sensors", sensors, ("noise_sd_m",))
    obstacles_raw = data.get("obstacles", [])
    if not isinstance(obstacles_raw, list):
        raise WorldError(f"obstacles must be an array of tables ([[obstacles]]) in {source}")
    obstacles = tuple(_obstacle(j, ob) for j, ob in enumerate(obstacles_raw))
    return World(
        name=str(data.get("name", Path(source).stem)),
        arena=arena,
        obstacles=obstacles,
        body=body,
        start_pose=start_pose,
        obstacles_solid=solid["obstacles"],
        walls_solid=solid["walls"],
        noise_sd_m=_number("sensors.noise_sd_m", sensors.get("noise_sd_m", 0.0)),
    )


def _table(data: dict, key: str, required: bool = True) -> dict:
    value = data.get(key)
    if value is None:
        if required:
            raise WorldError(f"{key} is missing (a [{key}] table is required)")
        return {}
    if not isinstance(value, dict):
        raise WorldError(f"{key} must be a table, got {type(value).__name__}")
    return value


def _known(where: str, table: dict, allowed: tuple) -> None:
    for key in table:
        if key not in allowed:
            dotted = f"{where}.{key}" if where else key
            raise WorldError(f"{dotted} is not a known key (allowed: {', '.join(allowed)})")


def _number(key: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise WorldError(f"{key} must be a number, got {value!r}")
    return float(value)


def _pair(key: str, value) -> tuple[float, float]:
    if not (isinstance(value, list | tuple) and len(value) == 2):
        raise WorldError(f"{key} must be a pair [x, y], got {value!r}")
    return _number(f"{key}[0]", value[0]), _number(f"{key}[1]", value[1])


def _arena(t: dict) -> ArenaShape:
    shape = t.get("shape", "circle")
    if shape == "circle":
        _known("arena", t, ("shape", "radius_m"))
        if "radius_m" not in t:
            raise WorldError("arena.radius_m is missing (required for a circular arena)")
        return ArenaShape("circle", radius_m=_number("arena.radius_m", t["radius_m"]))
    if shape == "rectangle":
        _known("arena", t, ("shape", "width_m", "height_m"))
        for key in ("width_m", "height_m"):
            if key not in t:
                raise WorldError(f"arena.{key} is missing (required for a rectangular arena)")
        return ArenaShape(
            "rectangle",
            width_m=_number("arena.width_m", t["width_m"]),
            height_m=_number("arena.height_m", t["height_m"]),
        )
    raise WorldError(f"arena.shape must be one of {ARENA_SHAPES}, got {shape!r}")


_ROBOT_KEYS = (
    "preset",
    "name",
    "radius_m",
    "wheel_base_m",
    "max_wheel_mps",
    "sensor_angles_deg",
    "sensor_offsets_m",
    "max_range_m",
    "ir_model",
    "start",
)


def _robot(t: dict) -> tuple[Body, tuple[float, float, float]]:
    _known("robot", t, _ROBOT_KEYS)
    if "preset" in t:
        body = bodies.preset(t["preset"])
    else:
        for key in ("sensor_angles_deg", "max_range_m"):
            if key not in t:
                raise WorldError(f"robot.{key} is missing (required when robot.preset is unset)")
        body = bodies.custom_body(t["sensor_angles_deg"], t["max_range_m"])
    changes = {}
    for key in ("radius_m", "wheel_base_m", "max_wheel_mps", "max_range_m"):
        if key in t:
            changes[key] = _number(f"robot.{key}", t[key])
    if "name" in t:
        changes["name"] = str(t["name"])
    if "ir_model" in t:
        changes["ir_model"] = None if t["ir_model"] in ("none", "") else t["ir_model"]
    radius = changes.get("radius_m", body.radius_m)
    if "sensor_angles_deg" in t:
        try:
            angles = np.deg2rad(np.asarray(t["sensor_angles_deg"], dtype=np.float64).reshape(-1))
        except (TypeError, ValueError):
            raise WorldError("robot.sensor_angles_deg must be an array of numbers") from None
        changes["sensor_angles_rad"] = angles
        changes["sensor_offsets_m"] = bodies.rim_offsets(radius, angles)
    elif "radius_m" in t and body.name != "khepera2":
        changes["sensor_offsets_m"] = bodies.rim_offsets(radius, body.sensor_angles_rad)
    if "sensor_offsets_m" in t:
        try:
            changes["sensor_offsets_m"] = np.asarray(t["sensor_offsets_m"], dtype=np.float64)
        except (TypeError, ValueError):
            raise WorldError("robot.sensor_offsets_m must be an array of [x, y] pairs") from None
    body = body.replace(**changes) if changes else body
    start = t.get("start", {})
    if not isinstance(start, dict):
        raise WorldError("robot.start must be a table {x_m, y_m, heading_deg}")
    _known("robot.start", start, ("x_m", "y_m", "heading_deg"))
    pose = (
        _number("robot.start.x_m", start.get("x_m", 0.0)),
        _number("robot.start.y_m", start.get("y_m", 0.0)),
        math.radians(_number("robot.start.heading_deg", start.get("heading_deg", 0.0))),
    )
    return body, pose


_OBSTACLE_KEYS = {
    "circle": ("radius_m",),
    "square": ("side_m",),
    "triangle": ("side_m",),
    "rectangle": ("width_m", "height_m"),
    "polygon": ("vertices_m",),
}


def _obstacle(j: int, t: dict) -> Obstacle:
    if not isinstance(t, dict):
        raise WorldError(f"obstacles[{j}] must be a table")
    shape = t.get("shape")
    if shape not in OBSTACLE_SHAPES:
        raise WorldError(f"obstacles[{j}].shape must be one of {OBSTACLE_SHAPES}, got {shape!r}")
    needed = _OBSTACLE_KEYS[shape]
    _known(f"obstacles[{j}]", t, ("shape", "center_m", "rotation_deg", *needed))
    for key in needed:
        if key not in t:
            raise WorldError(f"obstacles[{j}].{key} is missing (required for a {shape})")
    center = _pair(f"obstacles[{j}].center_m", t.get("center_m", [0.0, 0.0]))
    if shape == "circle":
        radius = _number(f"obstacles[{j}].radius_m", t["radius_m"])
        _positive(f"obstacles[{j}].radius_m", radius)
        return Obstacle("circle", center, radius_m=radius)
    if shape == "polygon":
        try:
            local = np.asarray(t["vertices_m"], dtype=np.float64)
        except (TypeError, ValueError):
            raise WorldError(
                f"obstacles[{j}].vertices_m must be an array of [x, y] pairs"
            ) from None
        if local.ndim != 2 or local.shape[1] != 2:
            raise WorldError(f"obstacles[{j}].vertices_m must be an array of [x, y] pairs")
    else:
        for key in needed:
            _positive(f"obstacles[{j}].{key}", _number(f"obstacles[{j}].{key}", t[key]))
        local = _template(shape, t)
    rot = math.radians(_number(f"obstacles[{j}].rotation_deg", t.get("rotation_deg", 0.0)))
    c, s = math.cos(rot), math.sin(rot)
    verts = local @ np.array([[c, s], [-s, c]]) + np.asarray(center)
    if polygon_signed_area(verts) < 0:
        verts = verts[::-1].copy()
    return Obstacle(shape, center, vertices_m=np.ascontiguousarray(verts))


def _template(shape: str, t: dict) -> np.ndarray:
    """Vertices of a named shape centred on its centroid, before rotation."""
    if shape == "square":
        h = t["side_m"] / 2
        return np.array([(-h, -h), (h, -h), (h, h), (-h, h)], dtype=np.float64)
    if shape == "rectangle":
        w, h = t["width_m"] / 2, t["height_m"] / 2
        return np.array([(-w, -h), (w, -h), (w, h), (-w, h)], dtype=np.float64)
    # equilateral triangle, one vertex pointing along +y, centroid at the centre
    r = t["side_m"] / math.sqrt(3.0)
    angles = np.radians([90.0, 210.0, 330.0])
    return np.stack([r * np.cos(angles), r * np.sin(angles)], axis=1)
