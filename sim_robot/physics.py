"""pymunk side of the world: obstacle shapes, solid collisions, and a reference ray caster.

The obstacles live in a static pymunk ``Space`` (convex polygons as one ``Poly``; non-convex
ones split by ``pymunk.autogeometry.convex_decomposition``; circles as ``Circle``; a
rectangular arena's walls as ``Segment``). Solid collisions query that space with the robot's
disc (``Space.shape_query``) and push the disc out along the contact normal, which leaves the
motion along the surface intact: the robot slides. A circular arena wall has no pymunk shape
(pymunk has no hollow circle); it is handled exactly in closed form.

:func:`pymunk_ranges` casts the range finders with ``Space.segment_query_first``; it is the
cross-check for the numba ray caster in ``sim_robot.geometry`` (same answers to 1e-9 m in the
tests) and is about 10x slower, which is why the arena uses the kernel.
"""

from __future__ import annotations

import math

import numpy as np
import pymunk
import pymunk.autogeometry

from .geometry import _ray_circle, is_convex
from .world import World

#: at most this many push-outs per substep when resolving solid contacts
MAX_PUSHES = 16


def build_space(world: World) -> pymunk.Space:
    """A static pymunk space holding the world's obstacles.

    Parameters
    ----------
    world : World

    Returns
    -------
    pymunk.Space
        Convex obstacles as one ``Poly`` each, non-convex ones decomposed, circles as
        ``Circle``, a rectangular arena's walls as ``Segment`` (a circular wall has no shape).
    """
    space = pymunk.Space()
    static = space.static_body
    for j, ob in enumerate(world.obstacles):
        if ob.is_circle:
            shapes = [pymunk.Circle(static, ob.radius_m, ob.center_m)]
        elif is_convex(ob.vertices_m):
            shapes = [pymunk.Poly(static, [tuple(p) for p in ob.vertices_m])]
        else:
            ring = [tuple(p) for p in ob.vertices_m] + [tuple(ob.vertices_m[0])]
            parts = pymunk.autogeometry.convex_decomposition(ring, 0.0)
            shapes = [pymunk.Poly(static, [tuple(p) for p in part[:-1]]) for part in parts]
        for shape in shapes:
            shape.obstacle_index = j
        space.add(*shapes)
    if world.arena.shape == "rectangle":
        hw, hh = world.arena.width_m / 2, world.arena.height_m / 2
        corners = [(-hw, -hh), (hw, -hh), (hw, hh), (-hw, hh)]
        for k in range(4):
            seg = pymunk.Segment(static, corners[k], corners[(k + 1) % 4], 0.0)
            seg.obstacle_index = -1
            space.add(seg)
    return space


class SolidResolver:
    """Pushes the robot's disc out of solid obstacles (pymunk) and walls (closed form).

    Parameters
    ----------
    world : World
        Which of walls and obstacles are solid, the arena and the robot's radius.
    space : pymunk.Space
        From `build_space` of ``world``.
    """

    def __init__(self, world: World, space: pymunk.Space):
        self.world = world
        self.space = space
        self.walls_solid = world.walls_solid
        self.obstacles_solid = world.obstacles_solid
        self._robot = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
        self._disc = pymunk.Circle(self._robot, world.body.radius_m)

    def resolve(
        self, x_m: float, y_m: float, prev_x_m: float, prev_y_m: float
    ) -> tuple[float, float]:
        """The non-penetrating position nearest to a disc moved to (x_m, y_m).

        Pushes out along the deepest contact, keeps the disc inside solid walls, and repeats.
        If the pushes do not settle within ``MAX_PUSHES`` (a notch narrower than the robot),
        the disc stays at its previous position ``(prev_x_m, prev_y_m)``, which was valid.

        Parameters
        ----------
        x_m, y_m : float
            Where the step moved the disc's centre (m).
        prev_x_m, prev_y_m : float
            Its centre before the step (m), a valid position.

        Returns
        -------
        (x_m, y_m) : tuple of float
            The resolved centre (m).
        """
        for attempt in range(MAX_PUSHES + 1):
            if self.walls_solid:
                x_m, y_m = self._inside_walls(x_m, y_m)
            if not self.obstacles_solid:
                return x_m, y_m
            deepest = self._deepest_contact(x_m, y_m)
            if deepest is None:
                return x_m, y_m
            if attempt == MAX_PUSHES:
                break
            depth, nx, ny = deepest
            # the normal points from the robot into the obstacle; step back out
            x_m += nx * depth
            y_m += ny * depth
        return prev_x_m, prev_y_m

    def _deepest_contact(self, x_m: float, y_m: float) -> tuple[float, float, float] | None:
        """(depth < 0, normal x, normal y) of the deepest obstacle penetration, or None."""
        deepest = None
        self._robot.position = (x_m, y_m)
        for info in self.space.shape_query(self._disc):
            if getattr(info.shape, "obstacle_index", -1) < 0:
                continue  # rectangle wall segments: handled in closed form
            points = info.contact_point_set.points
            normal = info.contact_point_set.normal
            if not points or not (normal.x or normal.y):
                continue
            depth = min(p.distance for p in points)
            if depth < 0.0 and (deepest is None or depth < deepest[0]):
                deepest = (depth, normal.x, normal.y)
        return deepest

    def _inside_walls(self, x_m: float, y_m: float) -> tuple[float, float]:
        a, r = self.world.arena, self.world.body.radius_m
        if a.shape == "circle":
            d = math.hypot(x_m, y_m)
            limit = a.radius_m - r
            if d > limit:
                return x_m * limit / d, y_m * limit / d
            return x_m, y_m
        hw, hh = a.width_m / 2 - r, a.height_m / 2 - r
        return min(hw, max(-hw, x_m)), min(hh, max(-hh, y_m))


def pymunk_ranges(
    space: pymunk.Space, world: World, pose: tuple[float, float, float]
) -> np.ndarray:
    """Range finder readings computed with pymunk segment queries (reference, slow).

    Same conventions as ``Arena.read_sensors`` (noise-free): metres, ``max_range_m`` when
    nothing is hit, 0 when the sensor starts inside an obstacle.

    Parameters
    ----------
    space : pymunk.Space
        From `build_space` of ``world``.
    world : World
    pose : (x_m, y_m, heading_rad)

    Returns
    -------
    float64[n_sensors]
        Range of each range finder (m).
    """
    body = world.body
    x, y, th = pose
    out = np.empty(body.n_sensors, dtype=np.float64)
    flt = pymunk.ShapeFilter()
    for i in range(body.n_sensors):
        ox_b, oy_b = body.sensor_offsets_m[i]
        ox = x + math.cos(th) * ox_b - math.sin(th) * oy_b
        oy = y + math.sin(th) * ox_b + math.cos(th) * oy_b
        a = th + float(body.sensor_angles_rad[i])
        dx, dy = math.cos(a), math.sin(a)
        end = (ox + dx * body.max_range_m, oy + dy * body.max_range_m)
        hit = space.segment_query_first((ox, oy), end, 0.0, flt)
        best = body.max_range_m if hit is None else hit.alpha * body.max_range_m
        if world.arena.shape == "circle" and best > 0.0:
            best = min(best, _ray_circle(ox, oy, dx, dy, 0.0, 0.0, world.arena.radius_m))
        out[i] = best
    return out
