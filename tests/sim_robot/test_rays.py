"""Range finders against closed-form ray–circle and ray–segment geometry."""

import math

import numpy as np
import pytest

from sim_robot import Arena, load_world, world_from_dict
from sim_robot.physics import pymunk_ranges


def reference_ranges(world, pose):
    """Independent reference: solve each intersection as a 2x2 / quadratic system in numpy."""
    body = world.body
    x, y, th = pose
    out = []
    for off, ang in zip(body.sensor_offsets_m, body.sensor_angles_rad.astype(float), strict=True):
        rot = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
        o = np.array([x, y]) + rot @ off
        d = np.array([math.cos(th + ang), math.sin(th + ang)])
        hits = [body.max_range_m]
        inside = False
        for ob in world.obstacles:
            if ob.is_circle:
                c = np.array(ob.center_m)
                if np.sum((o - c) ** 2) <= ob.radius_m**2:
                    inside = True
                hits += circle_hits(o, d, c, ob.radius_m)
            else:
                v = ob.vertices_m
                if point_in_polygon(o, v):
                    inside = True
                for k in range(len(v)):
                    hits += segment_hits(o, d, v[k], v[(k + 1) % len(v)])
        a = world.arena
        if a.shape == "circle":
            hits += circle_hits(o, d, np.zeros(2), a.radius_m)
        else:
            hw, hh = a.width_m / 2, a.height_m / 2
            c = [(-hw, -hh), (hw, -hh), (hw, hh), (-hw, hh)]
            for k in range(4):
                hits += segment_hits(o, d, np.array(c[k]), np.array(c[(k + 1) % 4]))
        out.append(0.0 if inside else min(hits))
    return np.array(out)


def circle_hits(o, d, c, r):
    # |o + t d - c|^2 = r^2  ->  t^2 + 2 t d.(o-c) + |o-c|^2 - r^2 = 0
    b = 2 * d @ (o - c)
    cc = (o - c) @ (o - c) - r * r
    disc = b * b - 4 * cc
    if disc < 0:
        return []
    roots = [(-b - math.sqrt(disc)) / 2, (-b + math.sqrt(disc)) / 2]
    return [t for t in roots if t >= 0]


def segment_hits(o, d, a, b):
    m = np.column_stack([d, a - b])  # o + t d = a + u (b - a)
    if abs(np.linalg.det(m)) < 1e-14:
        return []
    t, u = np.linalg.solve(m, a - o)
    return [t] if t >= 0 and 0 <= u <= 1 else []


def point_in_polygon(p, v):
    from matplotlib.path import Path

    return bool(Path(v).contains_point(p))


@pytest.mark.parametrize("name", ["paper", "bench16", "khepera2", "khepera4"])
def test_ranges_match_closed_form_geometry_in_random_poses(worlds_dir, name):
    world = load_world(worlds_dir / f"{name}.toml")
    arena = Arena(world)
    rng = np.random.default_rng(1)
    a = world.arena
    half = a.radius_m if a.shape == "circle" else max(a.width_m, a.height_m) / 2
    n_hits = 0
    for _ in range(400):
        # poses anywhere, including inside obstacles and (pass-through walls) outside the arena
        pose = (*rng.uniform(-1.2 * half, 1.2 * half, 2), rng.uniform(-math.pi, math.pi))
        arena.reset(pose)
        got = arena.read_sensors()
        want = reference_ranges(world, arena.pose)
        np.testing.assert_allclose(got, want.astype(np.float32), atol=1e-6, rtol=0)
        n_hits += int(np.sum(want < world.body.max_range_m))
    assert n_hits > 100  # the poses really exercised hits, not just max range


def test_kernel_matches_pymunk_segment_queries(worlds_dir):
    world = load_world(worlds_dir / "khepera4.toml")  # rectangle walls, polygons, circle
    arena = Arena(world)
    rng = np.random.default_rng(2)
    compared = 0
    while compared < 300:
        pose = (*rng.uniform(-0.55, 0.55, 1), *rng.uniform(-0.45, 0.45, 1), rng.uniform(-3, 3))
        arena.reset(pose)
        if arena.touching.any():
            continue  # pymunk answers differently from inside a shape; compare outside only
        got = arena.read_sensors().astype(np.float64)
        np.testing.assert_allclose(got, pymunk_ranges(arena.space, world, arena.pose), atol=1e-6)
        compared += 1


def test_rim_sensor_at_centre_of_empty_circular_arena_reads_radius_minus_rim(base_world):
    world = world_from_dict(
        base_world(
            robot={
                "sensor_angles_deg": [0.0, 33.0, 90.0, 180.0],
                "max_range_m": 2.0,
                "radius_m": 0.04,
            }
        )
    )
    ranges = Arena(world).read_sensors()
    np.testing.assert_allclose(ranges, 1.0 - 0.04, atol=1e-6)


def test_face_of_square_straight_ahead(base_world):
    obstacles = [{"shape": "square", "center_m": [0.5, 0.0], "side_m": 0.2}]
    world = world_from_dict(
        base_world(
            obstacles=obstacles,
            robot={
                "sensor_angles_deg": [0.0],
                "max_range_m": 1.0,
                "radius_m": 0.03,
            },
        )
    )
    # face at x = 0.4, sensor on the rim at x = 0.03
    assert Arena(world).read_sensors()[0] == pytest.approx(0.37, abs=1e-6)


def test_nothing_in_range_reads_exactly_max_range(base_world):
    world = world_from_dict(base_world(robot={"sensor_angles_deg": [0, 90], "max_range_m": 0.3}))
    ranges = Arena(world).read_sensors()
    assert ranges.dtype == np.float32
    assert np.all(ranges == np.float32(0.3))


def test_sensor_inside_an_obstacle_reads_zero_and_all_readings_are_valid(worlds_dir):
    world = load_world(worlds_dir / "paper.toml")
    arena = Arena(world)
    square = world.obstacles[0]
    arena.reset((*square.center_m, 0.0))  # pass-through: the robot may stand inside it
    ranges = arena.read_sensors()
    assert np.all(ranges == 0.0)
    rng = np.random.default_rng(3)
    for _ in range(200):
        arena.reset((*rng.uniform(-0.7, 0.7, 2), rng.uniform(-4, 4)))
        r = arena.read_sensors()
        assert np.all(np.isfinite(r)) and np.all(r >= 0) and np.all(r <= world.body.max_range_m)
