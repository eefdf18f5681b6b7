"""Trajectory metrics, pictures and the IR response."""

import math

import numpy as np
import pytest

from sim_robot import Arena, ir_value, load_world, trajectory_metrics, world_from_dict
from sim_robot.ir import KHEPERA2_IR_TABLE
from sim_robot.render import (
    PATH_STEP_M,
    draw_world,
    path_points,
    save_trajectory,
    trajectory_figure,
)


def record(arena, wheels, dt=0.01):
    t, poses = [arena.t_s], [arena.pose]
    for left, right in wheels:
        arena.step(left, right, dt)
        t.append(arena.t_s)
        poses.append(arena.pose)
    return np.array(t), np.array(poses)


def test_metrics_of_a_recorded_run_equal_the_arena_counters(worlds_dir):
    arena = Arena.from_toml(worlds_dir / "paper.toml")
    rng = np.random.default_rng(0)
    wheels = []
    for _ in range(60):  # 60 random 0.5 s manoeuvres: crosses obstacles and the wall
        left, right = rng.uniform(-0.05, 0.2, 2)
        wheels += [(left, right)] * 50
    t, poses = record(arena, wheels)
    m = trajectory_metrics(arena.world, t, poses)
    s = arena.stats
    assert s.obstacle_entries + s.arena_exits > 0  # the run exercised the counters
    assert m["obstacle_entries"] == s.obstacle_entries
    assert m["arena_exits"] == s.arena_exits
    assert m["wall_contacts"] == s.wall_contacts
    assert m["time_in_obstacles_s"] == pytest.approx(s.time_in_obstacles_s, abs=1e-9)
    assert m["time_outside_arena_s"] == pytest.approx(s.time_outside_arena_s, abs=1e-9)
    assert m["distance_m"] == pytest.approx(s.distance_m, rel=1e-12)
    assert m["duration_s"] == pytest.approx(30.0)
    assert m["mean_speed_mps"] == pytest.approx(s.distance_m / 30.0)


def test_straight_line_distance_speed_and_coverage(base_world):
    world = world_from_dict(
        base_world(arena={"shape": "rectangle", "width_m": 1.0, "height_m": 1.0})
    )
    t = np.linspace(0.0, 4.0, 401)
    x = -0.39 + 0.195 * t  # along y = 0.025, the middle of a row of 0.05 m cells
    poses = np.column_stack([x, np.full_like(x, 0.025), np.zeros_like(x)])
    m = trajectory_metrics(world, t, poses, cell_m=0.05)
    assert m["distance_m"] == pytest.approx(0.78)
    assert m["mean_speed_mps"] == pytest.approx(0.195)
    assert m["coverage_cells_total"] == 400
    assert m["coverage_cells_visited"] == 16  # x from -0.39 to 0.39: columns 2..17
    assert m["coverage_fraction"] == pytest.approx(16 / 400)
    assert m["obstacle_entries"] == m["arena_exits"] == 0


def test_metrics_reject_malformed_input(worlds_dir):
    world = load_world(worlds_dir / "paper.toml")
    with pytest.raises(ValueError, match="shape"):
        trajectory_metrics(world, np.zeros(3), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="non-decreasing"):
        trajectory_metrics(world, np.array([0.0, 1.0, 0.5]), np.zeros((3, 3)))


def test_pictures_png_and_svg(tmp_path, worlds_dir):
    arena = Arena.from_toml(worlds_dir / "paper.toml")
    t, poses = record(arena, [(0.1, 0.12)] * 300)
    png = save_trajectory(arena.world, t, poses, tmp_path / "run.png", title="test")
    svg = save_trajectory(arena.world, t, poses, tmp_path / "run.svg")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert b"<svg" in svg.read_bytes()[:500]
    with pytest.raises(ValueError, match=r"\.png or \.svg"):
        save_trajectory(arena.world, t, poses, tmp_path / "run.jpg")
    fig = trajectory_figure(arena.world, t, poses)
    ax = fig.axes[0]
    n_obstacle_patches = len(arena.world.obstacles)
    assert len(ax.patches) >= 1 + n_obstacle_patches + 1  # wall, obstacles, robot
    assert len(ax.collections) == 1  # the time-coloured path


def test_the_path_is_drawn_through_a_point_per_path_step_travelled():
    # 1 m in 100,000 steps of 10 um: ~1 / PATH_STEP_M points, the first and last kept
    x = np.linspace(0.0, 1.0, 100_001)
    xy = np.column_stack([x, np.zeros_like(x)])
    keep = path_points(xy, PATH_STEP_M)
    assert keep[0] == 0 and keep[-1] == len(xy) - 1
    assert abs(len(keep) - 1 / PATH_STEP_M) <= 2
    assert np.all(np.diff(xy[keep, 0]) <= PATH_STEP_M + 1e-5)  # no gap wider than a step
    # steps wider than PATH_STEP_M: every point; at rest: the first and the last
    wide = np.column_stack([np.arange(10) * 2 * PATH_STEP_M, np.zeros(10)])
    assert path_points(wide, PATH_STEP_M).tolist() == list(range(10))
    assert path_points(np.zeros((50, 2)), PATH_STEP_M).tolist() == [0, 49]


def test_a_long_runs_picture_stays_small(tmp_path, worlds_dir):
    arena = Arena.from_toml(worlds_dir / "paper.toml")
    t, poses = record(arena, [(0.01, 0.011)] * 20_000)  # 200 s at 10 ms, ~0.1 mm a step
    svg = save_trajectory(arena.world, t, poses, tmp_path / "run.svg")
    segments = trajectory_figure(arena.world, t, poses).axes[0].collections[0]
    assert len(segments.get_segments()) < len(t) / 3
    assert svg.stat().st_size < 2_000_000


def test_draw_world_with_sensor_rays(worlds_dir):
    from matplotlib.figure import Figure

    arena = Arena.from_toml(worlds_dir / "paper.toml")
    fig = Figure()
    ax = fig.add_subplot()
    draw_world(arena.world, ax, pose=arena.pose, ranges=arena.read_sensors())
    assert len(ax.lines) == 1 + arena.body.n_sensors  # heading mark + one line per ray


def test_ir_response_follows_the_published_khepera2_table():
    d = KHEPERA2_IR_TABLE[:, 0]
    np.testing.assert_allclose(ir_value(d), KHEPERA2_IR_TABLE[:, 1])
    fine = ir_value(np.linspace(0.0, 0.2, 500))
    assert np.all(np.diff(fine) <= 0)  # nearer never reads lower
    assert fine[0] == 1023 and fine[-1] == 0 and fine.dtype == np.float32
    assert ir_value(0.015) == pytest.approx((1000 + 450) / 2)


def test_khepera2_arena_reads_ir(worlds_dir):
    arena = Arena.from_toml(worlds_dir / "khepera2.toml")
    far = arena.read_ir()
    assert np.all(far == 0)  # nothing within 0.12 m at the start pose
    square = arena.world.obstacles[0]
    cx, cy = square.center_m
    # 0.17 m left of the square's centre, facing it: the two front sensors see its corner
    arena.reset((cx - 0.17, cy, 0.0))
    near = arena.read_ir()
    assert near[2] > 0 and near[3] > 0
    np.testing.assert_allclose(near, ir_value(arena.read_sensors()), atol=1e-3)
    assert math.isfinite(float(near.sum()))
