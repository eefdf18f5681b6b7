"""Behaviour metrics come from the record, for any body; the world adds the arena figures."""

import tomllib

import numpy as np
import pytest

from hub.protocol import Description
from lab.behaviour import behaviour_metrics, path_metrics, world_of
from sim_robot import load_world, trajectory_metrics

PAPER_WORLD = "configs/worlds/paper.toml"


def _circle(n=200, radius_m=0.3):
    angle = np.linspace(0, 2 * np.pi, n)
    t_s = np.linspace(0, 2.0, n)
    poses = np.stack([radius_m * np.cos(angle), radius_m * np.sin(angle), angle], axis=1)
    return t_s, poses


def test_the_path_of_any_body_is_measured_from_its_poses_alone():
    t_s, poses = _circle()
    m = behaviour_metrics(t_s, poses)
    assert m["distance_m"] == pytest.approx(2 * np.pi * 0.3, rel=1e-3)
    assert m["duration_s"] == 2.0
    assert m["mean_speed_mps"] == pytest.approx(m["distance_m"] / 2.0)
    assert "obstacle_entries" not in m


def test_path_metrics_agree_with_the_simulators_definitions():
    t_s, poses = _circle()
    world = load_world(PAPER_WORLD)
    full = trajectory_metrics(world, t_s, poses)
    for key, value in path_metrics(t_s, poses).items():
        assert full[key] == pytest.approx(value)


def test_a_known_world_adds_the_arena_metrics():
    t_s, poses = _circle()
    m = behaviour_metrics(t_s, poses, load_world(PAPER_WORLD))
    assert {"obstacle_entries", "arena_exits", "coverage_fraction"} <= set(m)


def test_the_bodys_described_radius_is_its_disc():
    world = load_world(PAPER_WORLD)
    t_s = np.array([0.0, 1.0])
    # from far outside the arena to its centre: a wall crossing for any radius
    poses = np.array([[10.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    big = Description(
        role="body", id="0", kind="khepera", sensor_angles_rad=[0.0], max_range_m=0.1,
        wheel_base_m=0.05, radius_m=50.0, max_wheel_mps=1.0,
    )  # fmt: skip
    small = behaviour_metrics(t_s, poses, world)
    large = behaviour_metrics(t_s, poses, world, big)
    # a 50 m disc at the centre overlaps every obstacle; the world's own robot does not
    assert large["time_in_obstacles_s"] == 1.0
    assert small["time_in_obstacles_s"] == 0.0


def test_the_world_of_a_run_is_its_body_world_as_a_path_or_as_contents():
    assert world_of({"body": {"kind": "sim_robot", "params": {"world": PAPER_WORLD}}}) is not None
    with open(PAPER_WORLD, "rb") as f:
        contents = tomllib.load(f)
    world = world_of({"body": {"kind": "khepera", "params": {"world": contents}}})
    assert world is not None and len(world.obstacles) == len(load_world(PAPER_WORLD).obstacles)


def test_a_simulated_body_without_a_world_uses_the_default_and_a_real_one_has_none():
    assert world_of({"body": {"kind": "sim_robot"}}) is not None
    assert world_of({"body": {"kind": "khepera", "params": {}}}) is None
    assert world_of({}) is None
