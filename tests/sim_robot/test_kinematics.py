"""Differential-drive motion against closed-form arcs, and wheel saturation."""

import math

import numpy as np
import pytest

from sim_robot import Arena, arc_step, world_from_dict

WHEEL_BASE_M = 0.053


@pytest.fixture
def open_arena(base_world):
    """A robot alone in a big arena (pass-through walls), wheels capped at 0.2 m/s."""
    data = base_world(arena={"shape": "circle", "radius_m": 50.0})
    data["robot"].update(wheel_base_m=WHEEL_BASE_M, max_wheel_mps=0.2)
    return Arena(world_from_dict(data))


def test_equal_wheels_drive_a_straight_line(open_arena):
    open_arena.reset((0.1, -0.2, math.radians(30)))
    for _ in range(1000):
        open_arena.step(0.15, 0.15, 0.01)
    x, y, th = open_arena.pose
    assert x == pytest.approx(0.1 + 1.5 * math.cos(math.radians(30)), abs=1e-9)
    assert y == pytest.approx(-0.2 + 1.5 * math.sin(math.radians(30)), abs=1e-9)
    assert th == pytest.approx(math.radians(30), abs=1e-12)
    assert open_arena.stats.distance_m == pytest.approx(1.5, abs=1e-9)


def test_opposite_wheels_spin_in_place(open_arena):
    open_arena.reset((0.3, 0.4, 0.0))
    omega = 2 * 0.1 / WHEEL_BASE_M  # rad/s
    for _ in range(100):
        open_arena.step(-0.1, 0.1, 0.01)
    x, y, th = open_arena.pose
    assert (x, y) == (pytest.approx(0.3, abs=1e-12), pytest.approx(0.4, abs=1e-12))
    assert th == pytest.approx(math.remainder(omega * 1.0, math.tau), abs=1e-9)


@pytest.mark.parametrize("left, right", [(0.05, 0.15), (0.2, -0.05), (0.1, 0.11)])
def test_constant_wheel_speeds_follow_a_circle(open_arena, left, right):
    x0, y0, th0 = 0.0, 0.0, 0.7
    open_arena.reset((x0, y0, th0))
    v = (left + right) / 2
    w = (right - left) / WHEEL_BASE_M
    radius = v / w  # signed: > 0 turns left
    cx, cy = x0 - radius * math.sin(th0), y0 + radius * math.cos(th0)
    dt = 0.01
    for k in range(1, 2001):
        open_arena.step(left, right, dt)
        if k % 100 == 0:
            t = k * dt
            x, y, th = open_arena.pose
            want_x = cx + radius * math.sin(th0 + w * t)
            want_y = cy - radius * math.cos(th0 + w * t)
            assert x == pytest.approx(want_x, abs=1e-9)
            assert y == pytest.approx(want_y, abs=1e-9)
            assert math.remainder(th - (th0 + w * t), math.tau) == pytest.approx(0, abs=1e-9)


def test_one_long_step_equals_many_short_ones():
    one = arc_step(0.0, 0.0, 0.2, 0.07, 0.13, WHEEL_BASE_M, 1.0)
    pose = (0.0, 0.0, 0.2)
    for _ in range(1000):
        pose = arc_step(*pose, 0.07, 0.13, WHEEL_BASE_M, 0.001)
    np.testing.assert_allclose(pose, one, atol=1e-12)


def test_nearly_straight_motion_is_well_conditioned():
    x, y, th = arc_step(0.0, 0.0, 0.0, 0.1, 0.1 + 1e-13, WHEEL_BASE_M, 1.0)
    assert x == pytest.approx(0.1, abs=1e-12) and abs(y) < 1e-12


def test_wheel_speeds_saturate_at_the_body_maximum(open_arena):
    open_arena.step(5.0, -3.0, 0.01)
    assert open_arena.wheel_mps == (0.2, -0.2)
    saturated = open_arena.pose
    open_arena.reset()
    open_arena.step(0.2, -0.2, 0.01)
    assert open_arena.pose == saturated


def test_bad_step_arguments_are_rejected(open_arena):
    with pytest.raises(ValueError, match="dt_s"):
        open_arena.step(0.1, 0.1, 0.0)
    with pytest.raises(ValueError, match="wheel speeds"):
        open_arena.step(float("nan"), 0.1, 0.01)
