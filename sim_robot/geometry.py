"""Exact 2-D geometry kernels: ray casting, clearances, polygon checks.

The world is flattened once into a few numpy arrays (:class:`Geometry`) so that the hot
kernels (numba, no Python objects, no allocation) can cast every range finder of a step in
one call. These kernels are the exact analytic reference (ray–segment and ray–circle
intersections); pymunk holds the same shapes for collisions and cross-validation
(``sim_robot.physics``).

Conventions: metres and radians; polygons are counter-clockwise vertex arrays; a circular arena
is centred on the origin, a rectangular one spans ``[-w/2, w/2] x [-h/2, h/2]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

#: obstacle kinds in :attr:`Geometry.obs_kind`
KIND_CIRCLE = 0
KIND_POLYGON = 1
#: arena kinds in :attr:`Geometry.wall_kind`
WALL_CIRCLE = 0
WALL_RECTANGLE = 1

#: distance within which the robot's disc counts as touching an obstacle or wall (m). Solid
#: collisions leave the disc exactly touching; this absorbs their floating-point residue.
CONTACT_TOLERANCE_M = 1e-9


@dataclass(frozen=True, eq=False)
class Geometry:
    """A world's shapes as flat arrays for the kernels.

    Attributes
    ----------
    obs_kind : int8[n_obstacles]
        ``KIND_CIRCLE`` or ``KIND_POLYGON``.
    obs_circle : float64[n_obstacles, 3]
        ``(cx, cy, r)`` of circular obstacles (zeros for polygons).
    poly_vertex : float64[n_vertices, 2]
        Vertices of all polygon obstacles, counter-clockwise, concatenated.
    obs_start : int64[n_obstacles + 1]
        Obstacle ``j`` owns ``poly_vertex[obs_start[j]:obs_start[j + 1]]`` (empty for circles).
    wall_kind : int
        ``WALL_CIRCLE`` or ``WALL_RECTANGLE``.
    wall_param : float64[2]
        ``(radius, 0)`` for a circle, ``(half_width, half_height)`` for a rectangle.
    """

    obs_kind: np.ndarray
    obs_circle: np.ndarray
    poly_vertex: np.ndarray
    obs_start: np.ndarray
    wall_kind: int
    wall_param: np.ndarray

    @property
    def n_obstacles(self) -> int:
        """Number of obstacles (circles and polygons)."""
        return int(self.obs_kind.shape[0])


# ---------------------------------------------------------------- scalar helpers (numba)


@njit(cache=True, nogil=True)
def _point_in_polygon(px, py, verts, i0, i1):
    """Crossing-number test: is (px, py) strictly inside polygon ``verts[i0:i1]``?"""
    inside = False
    j = i1 - 1
    for i in range(i0, i1):
        xi = verts[i, 0]
        yi = verts[i, 1]
        xj = verts[j, 0]
        yj = verts[j, 1]
        if (yi > py) != (yj > py):
            x_cross = xi + (py - yi) * (xj - xi) / (yj - yi)
            if px < x_cross:
                inside = not inside
        j = i
    return inside


@njit(cache=True, nogil=True)
def _dist_point_segment(px, py, ax, ay, bx, by):
    ex = bx - ax
    ey = by - ay
    len2 = ex * ex + ey * ey
    u = 0.0
    if len2 > 0.0:
        u = ((px - ax) * ex + (py - ay) * ey) / len2
        if u < 0.0:
            u = 0.0
        elif u > 1.0:
            u = 1.0
    dx = px - (ax + u * ex)
    dy = py - (ay + u * ey)
    return math.sqrt(dx * dx + dy * dy)


@njit(cache=True, nogil=True)
def _obstacle_clearance(px, py, j, obs_kind, obs_circle, poly_vertex, obs_start):
    """Distance from a point to obstacle ``j`` (0 when the point is inside it)."""
    if obs_kind[j] == KIND_CIRCLE:
        dx = px - obs_circle[j, 0]
        dy = py - obs_circle[j, 1]
        d = math.sqrt(dx * dx + dy * dy) - obs_circle[j, 2]
        return d if d > 0.0 else 0.0
    i0 = obs_start[j]
    i1 = obs_start[j + 1]
    if _point_in_polygon(px, py, poly_vertex, i0, i1):
        return 0.0
    best = math.inf
    k = i1 - 1
    for i in range(i0, i1):
        d = _dist_point_segment(
            px, py, poly_vertex[k, 0], poly_vertex[k, 1], poly_vertex[i, 0], poly_vertex[i, 1]
        )
        if d < best:
            best = d
        k = i
    return best


@njit(cache=True, nogil=True)
def _wall_margin(px, py, wall_kind, wall_param):
    """Signed distance from a point to the arena wall: > 0 inside, < 0 outside."""
    if wall_kind == WALL_CIRCLE:
        return wall_param[0] - math.sqrt(px * px + py * py)
    mx = wall_param[0] - abs(px)
    my = wall_param[1] - abs(py)
    if mx >= 0.0 and my >= 0.0:
        return min(mx, my)
    # outside: Euclidean distance to the rectangle, negated
    ox = -mx if mx < 0.0 else 0.0
    oy = -my if my < 0.0 else 0.0
    return -math.sqrt(ox * ox + oy * oy)


@njit(cache=True, nogil=True)
def _ray_segment(ox, oy, dx, dy, ax, ay, bx, by):
    """Distance along the unit ray (o, d) to segment ab, or inf when missed."""
    ex = bx - ax
    ey = by - ay
    denom = dx * ey - dy * ex
    if denom == 0.0:
        return math.inf  # parallel (a grazing, collinear ray sees no face)
    wx = ax - ox
    wy = ay - oy
    t = (wx * ey - wy * ex) / denom
    u = (wx * dy - wy * dx) / denom
    if t >= 0.0 and 0.0 <= u <= 1.0:
        return t
    return math.inf


@njit(cache=True, nogil=True)
def _ray_circle(ox, oy, dx, dy, cx, cy, r):
    """Smallest non-negative distance along the unit ray (o, d) to the circle, or inf."""
    wx = ox - cx
    wy = oy - cy
    b = wx * dx + wy * dy
    c = wx * wx + wy * wy - r * r
    disc = b * b - c
    if disc < 0.0:
        return math.inf
    s = math.sqrt(disc)
    t0 = -b - s
    if t0 >= 0.0:
        return t0
    t1 = -b + s
    if t1 >= 0.0:
        return t1
    return math.inf


# ---------------------------------------------------------------- kernels


@njit(cache=True, nogil=True)
def cast_rays(
    x,
    y,
    heading,
    sensor_offsets,
    sensor_angles,
    max_range,
    obs_kind,
    obs_circle,
    poly_vertex,
    obs_start,
    wall_kind,
    wall_param,
    out,
):
    """Range of each sensor of a robot at pose (x, y, heading), written into ``out``.

    A sensor at body-frame offset ``sensor_offsets[i]`` looks along ``heading +
    sensor_angles[i]``. Its range is the distance to the first obstacle face or wall crossing,
    capped at ``max_range``; 0 when the sensor itself lies inside an obstacle. The wall is a
    curve, not a solid: a sensor outside the arena sees it from outside.

    Parameters
    ----------
    x, y, heading : float
        The robot's pose (m, rad).
    sensor_offsets : float64[k, 2]
        Sensor positions in the body frame.
    sensor_angles : float64[k]
        Sensor facings (rad, counter-clockwise from forward).
    max_range : float
    obs_kind, obs_circle, poly_vertex, obs_start, wall_kind, wall_param : arrays
        The world's flattened geometry (``World.geometry``).
    out : float32[k]
        Written: the range of each sensor (m).
    """
    ch = math.cos(heading)
    sh = math.sin(heading)
    n_obs = obs_kind.shape[0]
    for i in range(sensor_angles.shape[0]):
        ox = x + ch * sensor_offsets[i, 0] - sh * sensor_offsets[i, 1]
        oy = y + sh * sensor_offsets[i, 0] + ch * sensor_offsets[i, 1]
        a = heading + sensor_angles[i]
        dx = math.cos(a)
        dy = math.sin(a)
        best = max_range
        for j in range(n_obs):
            if obs_kind[j] == KIND_CIRCLE:
                cx = obs_circle[j, 0]
                cy = obs_circle[j, 1]
                r = obs_circle[j, 2]
                if (ox - cx) ** 2 + (oy - cy) ** 2 <= r * r:
                    best = 0.0
                    break
                t = _ray_circle(ox, oy, dx, dy, cx, cy, r)
                if t < best:
                    best = t
            else:
                i0 = obs_start[j]
                i1 = obs_start[j + 1]
                if _point_in_polygon(ox, oy, poly_vertex, i0, i1):
                    best = 0.0
                    break
                k = i1 - 1
                for m in range(i0, i1):
                    t = _ray_segment(
                        ox,
                        oy,
                        dx,
                        dy,
                        poly_vertex[k, 0],
                        poly_vertex[k, 1],
                        poly_vertex[m, 0],
                        poly_vertex[m, 1],
                    )
                    if t < best:
                        best = t
                    k = m
        if best > 0.0:
            if wall_kind == WALL_CIRCLE:
                t = _ray_circle(ox, oy, dx, dy, 0.0, 0.0, wall_param[0])
                if t < best:
                    best = t
            else:
                hw = wall_param[0]
                hh = wall_param[1]
                t = min(
                    _ray_segment(ox, oy, dx, dy, -hw, -hh, hw, -hh),
                    _ray_segment(ox, oy, dx, dy, hw, -hh, hw, hh),
                    _ray_segment(ox, oy, dx, dy, hw, hh, -hw, hh),
                    _ray_segment(ox, oy, dx, dy, -hw, hh, -hw, -hh),
                )
                if t < best:
                    best = t
        out[i] = best


@njit(cache=True, nogil=True)
def disc_state(
    xs,
    ys,
    radius,
    obs_kind,
    obs_circle,
    poly_vertex,
    obs_start,
    wall_kind,
    wall_param,
    overlap,
    outside,
    wall_touch,
):
    """Where a robot disc of ``radius`` stands, for each centre ``(xs[k], ys[k])``.

    Parameters
    ----------
    xs, ys : float64[n]
        Centres (m).
    radius : float
        The disc (m).
    obs_kind, obs_circle, poly_vertex, obs_start, wall_kind, wall_param : arrays
        The world's flattened geometry (``World.geometry``).
    overlap : bool[n, n_obstacles]
        Written: the disc touches or overlaps obstacle j.
    outside : bool[n]
        Written: the centre is outside the arena.
    wall_touch : bool[n]
        Written: the disc touches or crosses the wall.
    """
    n_obs = obs_kind.shape[0]
    for k in range(xs.shape[0]):
        px = xs[k]
        py = ys[k]
        for j in range(n_obs):
            c = _obstacle_clearance(px, py, j, obs_kind, obs_circle, poly_vertex, obs_start)
            overlap[k, j] = c <= radius + CONTACT_TOLERANCE_M
        m = _wall_margin(px, py, wall_kind, wall_param)
        outside[k] = m < 0.0
        wall_touch[k] = abs(m) <= radius + CONTACT_TOLERANCE_M


@njit(cache=True, nogil=True)
def disc_update(
    px, py, radius, obs_kind, obs_circle, poly_vertex, obs_start, wall_kind, wall_param, overlap
):
    """One robot position: update ``overlap[j]`` in place (same rule as :func:`disc_state`).

    Parameters
    ----------
    px, py : float
        The disc's centre (m).
    radius : float
        The disc (m).
    obs_kind, obs_circle, poly_vertex, obs_start, wall_kind, wall_param : arrays
        The world's flattened geometry (``World.geometry``).
    overlap : bool[n_obstacles]
        Read: the previous contacts; written: whether the disc touches or overlaps
        obstacle j now.

    Returns
    -------
    new_entries : int
        Obstacles overlapped now but not in the previous ``overlap``.
    any_overlap, outside, wall_touch : bool
        The disc overlaps some obstacle; its centre is outside the arena; it touches or
        crosses the wall.
    """
    entries = 0
    any_overlap = False
    for j in range(obs_kind.shape[0]):
        c = _obstacle_clearance(px, py, j, obs_kind, obs_circle, poly_vertex, obs_start)
        now = c <= radius + CONTACT_TOLERANCE_M
        if now and not overlap[j]:
            entries += 1
        overlap[j] = now
        any_overlap = any_overlap or now
    m = _wall_margin(px, py, wall_kind, wall_param)
    return entries, any_overlap, m < 0.0, abs(m) <= radius + CONTACT_TOLERANCE_M


# ---------------------------------------------------------------- plain-Python helpers


def polygon_signed_area(vertices_m: np.ndarray) -> float:
    """Shoelace area; positive for counter-clockwise vertices."""
    v = np.asarray(vertices_m, dtype=np.float64)
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _segments_cross(p1, p2, q1, q2) -> bool:
    """Do closed segments p1p2 and q1q2 share a point?"""

    def orient(a, b, c):
        return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])

    def on_segment(a, b, c):
        return min(a[0], b[0]) <= c[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= c[1] <= max(
            a[1], b[1]
        )

    d1, d2 = orient(q1, q2, p1), orient(q1, q2, p2)
    d3, d4 = orient(p1, p2, q1), orient(p1, p2, q2)
    if ((d1 > 0) != (d2 > 0)) and ((d3 > 0) != (d4 > 0)) and d1 and d2 and d3 and d4:
        return True
    return (
        (d1 == 0 and on_segment(q1, q2, p1))
        or (d2 == 0 and on_segment(q1, q2, p2))
        or (d3 == 0 and on_segment(p1, p2, q1))
        or (d4 == 0 and on_segment(p1, p2, q2))
    )


def polygon_self_intersection(vertices_m: np.ndarray) -> tuple[int, int] | None:
    """First pair of non-adjacent edges (i, j) that touch or cross, or None if simple.

    Edge ``i`` joins vertex ``i`` to vertex ``i + 1`` (wrapping).
    """
    v = [tuple(map(float, p)) for p in np.asarray(vertices_m)]
    n = len(v)
    for i in range(n):
        for j in range(i + 1, n):
            if j == i + 1 or (i == 0 and j == n - 1):
                continue  # adjacent edges share a vertex by construction
            if _segments_cross(v[i], v[(i + 1) % n], v[j], v[(j + 1) % n]):
                return i, j
    return None


def is_convex(vertices_m: np.ndarray) -> bool:
    """True when a counter-clockwise simple polygon has no reflex vertex."""
    v = np.asarray(vertices_m, dtype=np.float64)
    e = np.roll(v, -1, axis=0) - v
    cross = e[:, 0] * np.roll(e[:, 1], -1) - e[:, 1] * np.roll(e[:, 0], -1)
    return bool(np.all(cross >= 0.0))
