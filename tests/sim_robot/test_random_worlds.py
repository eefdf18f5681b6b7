"""Random worlds with star-shaped (often non-convex) polygons: rays and solid collisions."""

import math

import numpy as np
import pytest

from sim_robot import Arena, WorldError, world_from_dict
from sim_robot.physics import pymunk_ranges
from sim_robot.world import disc_flags


def star_polygon(rng, n_vertices, r_min, r_max):
    angles = np.sort(rng.uniform(0, 2 * np.pi, n_vertices))
    radii = rng.uniform(r_min, r_max, n_vertices)
    return np.column_stack([radii * np.cos(angles), radii * np.sin(angles)]).tolist()


def random_world(rng, solid=False):
    """A rectangular or circular arena with 4-6 star polygons and circles, robot at the origin."""
    obstacles = []
    while len(obstacles) < rng.integers(4, 7):
        angle, dist = rng.uniform(0, 2 * np.pi), rng.uniform(0.25, 0.6)
        center = [dist * math.cos(angle), dist * math.sin(angle)]
        if rng.random() < 0.7:
            verts = star_polygon(rng, int(rng.integers(3, 9)), 0.03, 0.12)
            obstacles.append({"shape": "polygon", "center_m": center, "vertices_m": verts})
        else:
            obstacles.append({"shape": "circle", "center_m": center, "radius_m": 0.08})
    arena = (
        {"shape": "circle", "radius_m": 0.8}
        if rng.random() < 0.5
        else {"shape": "rectangle", "width_m": 1.6, "height_m": 1.5}
    )
    data = {
        "arena": arena,
        "physics": {"obstacles": "solid" if solid else "pass", "walls": "solid"},
        "robot": {
            "sensor_angles_deg": np.linspace(-180, 180, 12, endpoint=False).tolist(),
            "max_range_m": 0.4,
            "radius_m": 0.03,
            "max_wheel_mps": 0.3,
        },
        "obstacles": obstacles,
    }
    try:
        return world_from_dict(data)
    except WorldError:
        return None  # a random obstacle landed on the robot's start: draw again


def worlds(seed, n, solid=False):
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        w = random_world(rng, solid)
        if w is not None:
            out.append(w)
    return out


def test_kernel_matches_pymunk_in_random_worlds_with_non_convex_polygons():
    rng = np.random.default_rng(11)
    compared = 0
    for world in worlds(10, 8):
        arena = Arena(world)
        for _ in range(60):
            arena.reset((*rng.uniform(-0.7, 0.7, 2), rng.uniform(-math.pi, math.pi)))
            if arena.touching.any():
                continue
            got = arena.read_sensors().astype(np.float64)
            want = pymunk_ranges(arena.space, world, arena.pose)
            np.testing.assert_allclose(got, want, atol=1e-6)
            compared += 1
    assert compared > 200


@pytest.mark.parametrize("seed", [20, 21, 22])
def test_solid_obstacles_and_walls_are_never_penetrated(seed):
    rng = np.random.default_rng(seed)
    collisions = 0
    for world in worlds(seed, 3, solid=True):
        arena = Arena(world)
        poses = []
        for _ in range(100):  # 100 random 0.5 s manoeuvres, mostly forward
            left, right = rng.uniform(-0.05, 0.3, 2)
            for _ in range(50):
                arena.step(left, right, 0.01)
                poses.append(arena.pose)
        p = np.array(poses)
        # shrink the disc by 1 um: anything still overlapping is a real penetration
        overlap, outside, _ = disc_flags(world, p[:, 0], p[:, 1], world.body.radius_m - 1e-6)
        assert not overlap.any()
        assert not outside.any() and arena.stats.arena_exits == 0
        assert arena.stats.distance_m > 0.5  # it did move (sliding, not stuck)
        collisions += arena.stats.obstacle_entries
    assert collisions >= 5  # the robots really ran into obstacles
