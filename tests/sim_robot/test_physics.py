"""Pass-through versus solid obstacles and walls; entry, exit and contact bookkeeping."""

import math

import numpy as np
import pytest

from sim_robot import Arena, world_from_dict

RADIUS_M = 0.03


def square_world(base_world, obstacles="pass", walls="pass"):
    data = base_world(
        obstacles=[{"shape": "square", "center_m": [0.5, 0.0], "side_m": 0.2}],
        physics={"obstacles": obstacles, "walls": walls},
    )
    data["robot"].update(radius_m=RADIUS_M, max_wheel_mps=0.5)
    return world_from_dict(data)


def drive(arena, left, right, seconds, dt=0.01):
    for _ in range(round(seconds / dt)):
        arena.step(left, right, dt)


def test_pass_through_obstacle_is_crossed_and_counted_once(base_world):
    arena = Arena(square_world(base_world))
    drive(arena, 0.2, 0.2, 4.0)  # from x=0 to x=0.8, through the square spanning 0.4..0.6
    assert arena.pose[0] == pytest.approx(0.8, abs=1e-9)
    assert arena.stats.obstacle_entries == 1
    # the disc overlaps the square while its centre is within 0.37..0.63 m: 0.26 m at 0.2 m/s
    assert arena.stats.time_in_obstacles_s == pytest.approx(1.3, abs=0.011)
    assert not arena.contact


def test_contact_flag_while_overlapping_a_pass_through_obstacle(base_world):
    arena = Arena(square_world(base_world))
    drive(arena, 0.2, 0.2, 2.0)  # centre at x=0.4: on the face
    assert arena.contact
    assert arena.touching.tolist() == [True]


def test_solid_obstacle_stops_the_robot_at_contact(base_world):
    arena = Arena(square_world(base_world, obstacles="solid"))
    drive(arena, 0.2, 0.2, 4.0)
    x, y, _ = arena.pose
    assert x == pytest.approx(0.4 - RADIUS_M, abs=1e-9)
    assert y == pytest.approx(0.0, abs=1e-12)
    assert arena.contact
    assert arena.stats.obstacle_entries == 1
    assert arena.read_sensors()[2] == pytest.approx(0.0, abs=1e-6)  # forward sensor on the face


def test_solid_obstacle_lets_the_robot_slide_along_its_face(base_world):
    arena = Arena(square_world(base_world, obstacles="solid"))
    arena.reset((0.0, -0.08, math.radians(10)))  # heading into the face, slightly upward
    drive(arena, 0.2, 0.2, 3.0)  # meets the face at y = -0.015 after 0.376 m
    x, y, _ = arena.pose
    assert x == pytest.approx(0.4 - RADIUS_M, abs=1e-9)  # pressed against the face
    # then slides up it at 0.2 sin(10 deg) m/s for the remaining 1.12 s instead of sticking
    assert y == pytest.approx(-0.015 + 1.12 * 0.2 * math.sin(math.radians(10)), abs=2e-3)


def test_solid_circular_wall_keeps_the_robot_inside(base_world):
    arena = Arena(square_world(base_world, walls="solid"))
    arena.reset((0.0, 0.0, math.pi / 2))
    drive(arena, 0.5, 0.45, 20.0)  # a 0.5 m-radius circle centred at (-0.5, 0): hits the wall
    x, y, _ = arena.pose
    assert math.hypot(x, y) <= 1.0 - RADIUS_M + 1e-12
    assert arena.stats.arena_exits == 0
    assert arena.stats.wall_contacts >= 1


def test_pass_through_wall_lets_the_robot_leave_and_counts_the_exit(base_world):
    arena = Arena(square_world(base_world))
    arena.reset((0.0, 0.0, -math.pi / 2))
    drive(arena, 0.5, 0.5, 3.0)  # 1.5 m straight down: leaves the 1 m arena
    assert arena.outside
    assert arena.stats.arena_exits == 1
    assert arena.stats.time_outside_arena_s == pytest.approx(1.0, abs=0.011)
    drive(arena, -0.5, -0.5, 3.0)  # back in
    assert not arena.outside and arena.stats.arena_exits == 1


def test_solid_rectangular_walls_and_non_convex_obstacle(base_world):
    # an L-shaped block; drive into its inner corner from the open side
    data = base_world(
        arena={"shape": "rectangle", "width_m": 1.0, "height_m": 0.8},
        obstacles=[
            {
                "shape": "polygon",
                "center_m": [0.3, 0.0],
                "vertices_m": [
                    [-0.1, -0.2],
                    [0.1, -0.2],
                    [0.1, 0.2],
                    [-0.1, 0.2],
                    [-0.1, 0.1],
                    [0.0, 0.1],
                    [0.0, -0.1],
                    [-0.1, -0.1],
                ],
            }
        ],
        physics={"obstacles": "solid", "walls": "solid"},
    )
    data["robot"].update(radius_m=RADIUS_M, max_wheel_mps=0.5)
    arena = Arena(world_from_dict(data))
    drive(arena, 0.3, 0.3, 3.0)
    x, y, _ = arena.pose
    assert x == pytest.approx(0.3 - RADIUS_M, abs=1e-6)  # stopped by the notch floor at x=0.3
    assert arena.contact
    arena.reset((0.0, 0.0, math.radians(135)))
    drive(arena, 0.4, 0.4, 5.0)  # into the top-left corner
    x, y, _ = arena.pose
    assert x == pytest.approx(-0.5 + RADIUS_M, abs=1e-9)
    assert y == pytest.approx(0.4 - RADIUS_M, abs=1e-9)


def test_stats_and_time_restart_on_reset(base_world):
    arena = Arena(square_world(base_world))
    drive(arena, 0.2, 0.2, 4.0)
    arena.reset()
    assert arena.t_s == 0.0 and arena.stats.obstacle_entries == 0
    assert arena.pose == (0.0, 0.0, 0.0)


def test_noise_is_off_by_default_and_seeded_when_on(base_world):
    data = base_world(sensors={"noise_sd_m": 0.01})
    a, b, c = (Arena(world_from_dict(data), seed=s) for s in (5, 5, 6))
    ra, rb, rc = a.read_sensors(), b.read_sensors(), c.read_sensors()
    np.testing.assert_array_equal(ra, rb)
    assert not np.array_equal(ra, rc)
    assert np.all((ra >= 0) & (ra <= 0.5))
    quiet = Arena(world_from_dict(base_world()), seed=5)
    np.testing.assert_array_equal(quiet.read_sensors(), quiet.read_sensors())


def test_gap_narrower_than_the_robot_between_obstacle_and_wall_is_not_squeezed_through(
    base_world,
):
    # a circle 0.05 m from the solid wall; the robot (0.06 m wide) drives into the gap
    data = base_world(
        obstacles=[{"shape": "circle", "center_m": [0.85, 0.0], "radius_m": 0.1}],
        physics={"obstacles": "solid", "walls": "solid"},
    )
    data["robot"].update(radius_m=RADIUS_M, max_wheel_mps=0.5)
    data["robot"]["start"] = {"x_m": 0.7, "y_m": -0.5, "heading_deg": 65.0}
    arena = Arena(world_from_dict(data))
    for _ in range(800):
        arena.step(0.3, 0.3, 0.01)
        x, y, _ = arena.pose
        assert math.hypot(x - 0.85, y) >= 0.1 + RADIUS_M - 1e-9
        assert math.hypot(x, y) <= 1.0 - RADIUS_M + 1e-9
    assert arena.contact and y < 0.0  # wedged on the near side of the gap
