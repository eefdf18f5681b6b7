"""Decoding schemes: wheel speeds from hand-made spike batches."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hub.decoding import center_of_activity, two_population, wheel_speeds
from hub.protocol import SpikeBatch, StepWindow
from hub.schemes import ConfigError
from tests.schemes.descriptions import body, context, points

PERIOD_MS = 10.0
RUN = "0" * 32


def W(step: int) -> StepWindow:
    """The window of ``step`` in the test run."""
    return StepWindow.of(RUN, step, PERIOD_MS / 1e3)


# A 5-channel culture: centre (0, 0), radius 1000 µm; channels at the centre, left (−x),
# right (+x), front (+y) and back (−y), 500 µm out.
CENTRE, LEFT, RIGHT, FRONT, BACK = range(5)
CROSS = points([[0, 0], [-500, 0], [500, 0], [0, 500], [0, -500], [-1000, 0], [1000, 0]])
# the two extra channels (5, 6) at ±1000 µm only set the radius to 1000 µm
WIDE = body(wheel_base_m=0.1, max_wheel_mps=1.0)  # limits far from the values tested


def batch(step: int, channels=(), t_ms=None) -> SpikeBatch:
    """Spikes of step ``step`` (window [step·10, step·10 + 10) ms), evenly spread by default."""
    channels = list(channels)
    if t_ms is None:
        t_ms = np.linspace(0.0, PERIOD_MS, len(channels), endpoint=False)
    return SpikeBatch(
        **W(step).stamp,
        channel=np.asarray(channels, dtype=np.uint32),
        t_ms=np.asarray(t_ms, dtype=np.float32),
    )


def ca_decoder(**params):
    params = {"turn_gain_rad_s_per_rad": 1.0, "speed_gain_mps": 0.4, **params}
    return center_of_activity(context("decoding", WIDE, CROSS, **params))


def expected(v, omega, b=0.1):
    return v - omega * b / 2, v + omega * b / 2


# --------------------------------------------------------------------------- center of activity


def test_ca_on_the_left_turns_left_at_a_speed_set_by_its_distance():
    m = ca_decoder()(batch(4, [LEFT] * 3), W(5))
    # d = 500 µm = 0.5 radius → v = 0.4 × 0.5 = 0.2 m/s; θ = +π/2 → ω = +π/2 rad/s
    assert m.step == 5
    assert (m.v_mps, m.omega_rad_s) == pytest.approx((0.2, math.pi / 2))
    assert (m.left_mps, m.right_mps) == pytest.approx(expected(0.2, math.pi / 2))
    assert m.right_mps > m.left_mps


def test_ca_on_the_right_turns_right():
    m = ca_decoder()(batch(0, [RIGHT]), W(1))
    assert m.omega_rad_s == pytest.approx(-math.pi / 2)
    assert m.left_mps > m.right_mps


def test_ca_in_front_goes_straight_and_behind_turns_fully():
    ahead = ca_decoder()(batch(0, [FRONT]), W(1))
    assert (ahead.v_mps, ahead.omega_rad_s) == pytest.approx((0.2, 0.0))
    assert ahead.left_mps == pytest.approx(ahead.right_mps)
    behind = ca_decoder()(batch(0, [BACK]), W(1))
    assert abs(behind.omega_rad_s) == pytest.approx(math.pi)


def test_ca_is_the_spike_weighted_mean_position():
    # 3 spikes left, 1 spike in front: CA = (−375, 125) µm
    m = ca_decoder()(batch(0, [LEFT, LEFT, LEFT, FRONT]), W(1))
    d_rel = math.hypot(-375, 125) / 1000
    theta = math.atan2(375, 125)
    assert (m.v_mps, m.omega_rad_s) == pytest.approx((0.4 * d_rel, theta))


def test_ca_at_the_centre_goes_straight_at_the_minimum_speed():
    m = ca_decoder(min_speed_mps=0.03)(batch(0, [LEFT, RIGHT, FRONT, BACK, CENTRE]), W(1))
    assert (m.left_mps, m.right_mps, m.omega_rad_s) == pytest.approx((0.03, 0.03, 0.0))


def test_ca_inside_the_dead_zone_goes_straight_at_the_minimum_speed():
    # 1 spike front + 9 at the centre: CA 50 µm ahead, inside a dead zone of 0.1 × 1000 µm
    m = ca_decoder(dead_zone_frac=0.1)(batch(0, [FRONT] + [CENTRE] * 9), W(1))
    assert (m.v_mps, m.omega_rad_s) == pytest.approx((0.02, 0.0))
    m = ca_decoder(dead_zone_frac=0.01)(batch(0, [FRONT] + [CENTRE] * 9), W(1))
    assert m.v_mps == pytest.approx(0.02)  # 0.4 × 0.05 = 0.02: the floor and the gain agree
    m = ca_decoder(dead_zone_frac=0.01, min_speed_mps=0.01)(batch(0, [BACK] + [CENTRE] * 9), W(1))
    assert (m.v_mps, abs(m.omega_rad_s)) == pytest.approx((0.02, math.pi))


def test_no_spike_in_the_window_goes_straight_at_the_minimum_speed():
    m = ca_decoder(min_speed_mps=0.05)(batch(0), W(1))
    assert (m.left_mps, m.right_mps, m.v_mps, m.omega_rad_s) == pytest.approx(
        (0.05,) * 2 + (0.05, 0)
    )


def test_a_running_centre_follows_the_ca_so_a_lasting_bias_stops_steering():
    decode = ca_decoder(centre_tau_s=0.05)  # moves 10 ms / 50 ms = 1/5 of the way each step
    m = decode(batch(0, [LEFT]), W(1))  # the first CA is judged from the geometric centre
    assert (m.v_mps, m.omega_rad_s) == pytest.approx((0.2, math.pi / 2))
    m = decode(batch(1, [LEFT]), W(2))  # centre now at (−100, 0): CA 400 µm left of it
    assert (m.v_mps, m.omega_rad_s) == pytest.approx((0.16, math.pi / 2))
    for k in range(2, 60):  # activity stays on the left: the centre catches up
        m = decode(batch(k, [LEFT]), W(k + 1))
    assert (m.v_mps, m.omega_rad_s) == pytest.approx((0.02, 0.0))
    m = decode(batch(60, [RIGHT] * 20), W(61))  # a departure from the usual CA steers again
    assert m.omega_rad_s == pytest.approx(-math.pi / 2)


def test_speed_is_limited_to_max_speed():
    m = ca_decoder(speed_gain_mps=10.0, max_speed_mps=0.3)(batch(0, [FRONT]), W(1))
    assert m.v_mps == pytest.approx(0.3)


def test_ca_averages_over_the_window_across_batches():
    decode = ca_decoder()  # 50 ms window: five 10 ms steps
    decode(batch(0, [LEFT]), W(1))
    m = decode(batch(1, [RIGHT]), W(2))  # left and right together: CA at the centre
    assert (m.v_mps, m.omega_rad_s) == pytest.approx((0.02, 0.0))
    for k in range(2, 5):
        m = decode(batch(k), W(k + 1))
    assert m.omega_rad_s == pytest.approx(0.0)  # both still inside [0, 50) ms
    m = decode(batch(5), W(6))  # window [10, 60): the left spike (t = 0) has left it
    assert m.omega_rad_s == pytest.approx(-math.pi / 2)
    m = decode(batch(6), W(7))  # window [20, 70): empty
    assert (m.v_mps, m.omega_rad_s) == pytest.approx((0.02, 0.0))


def test_a_window_that_is_not_a_whole_number_of_steps_cuts_inside_a_batch():
    decode = ca_decoder(window_ms=15.0)
    decode(batch(0, [RIGHT, LEFT], t_ms=[2.0, 6.0]), W(1))
    # after batch 1 the window is [5, 20) ms: the right spike (2 ms) is out, the left one in
    m = decode(batch(1), W(2))
    assert m.omega_rad_s == pytest.approx(math.pi / 2)


def test_a_culture_restart_clears_the_window():
    decode = ca_decoder()
    decode(batch(7, [LEFT]), W(8))
    m = decode(batch(0, [RIGHT]), W(9))  # time went back: the left spike is forgotten
    assert m.omega_rad_s == pytest.approx(-math.pi / 2)


def test_spikes_on_undescribed_channels_are_ignored():
    decode = ca_decoder()
    m = decode(batch(0, [LEFT, 99, 1234]), W(1))
    assert m.omega_rad_s == pytest.approx(math.pi / 2)
    m = ca_decoder()(batch(0, [99]), W(1))
    assert (m.v_mps, m.omega_rad_s) == pytest.approx((0.02, 0.0))


def test_channel_ids_need_not_be_indices():
    culture = points([[-500, 0], [500, 0], [0, 1000], [0, -1000]], channels=[70, 3, 12, 40])
    decode = center_of_activity(context("decoding", WIDE, culture, turn_gain_rad_s_per_rad=1.0))
    assert decode(batch(0, [70]), W(1)).omega_rad_s == pytest.approx(math.pi / 2)
    assert decode(batch(1, [3, 3, 3]), W(2)).omega_rad_s == pytest.approx(-math.pi / 2)


def test_large_channel_ids_are_looked_up_too():
    big = [1 << 31, 70_000, 12, 1 << 20]
    culture = points([[-500, 0], [500, 0], [0, 1000], [0, -1000]], channels=big)
    ctx = context("decoding", WIDE, culture, turn_gain_rad_s_per_rad=1.0)
    m = center_of_activity(ctx)(batch(0, [1 << 31, 5, (1 << 31) + 1]), W(1))
    assert m.omega_rad_s == pytest.approx(math.pi / 2)  # only channel 2³¹ (left) counts
    m = center_of_activity(ctx)(batch(0, [70_000] * 3 + [1 << 20]), W(1))
    assert m.omega_rad_s == pytest.approx(math.atan2(-375, -250))  # CA at (375, −250) µm


def test_wheels_are_clipped_to_the_body_limit_keeping_the_turn():
    paper7 = body()  # wheels at most 0.2 m/s, wheel base 0.053 m
    decode = center_of_activity(
        context("decoding", paper7, CROSS, speed_gain_mps=5.0, turn_gain_rad_s_per_rad=50.0)
    )
    m = decode(batch(0, [LEFT]), W(1))
    assert max(abs(m.left_mps), abs(m.right_mps)) == pytest.approx(0.2)
    assert m.right_mps == pytest.approx(0.2) and m.left_mps == pytest.approx(-0.2)
    assert m.omega_rad_s == pytest.approx(0.4 / 0.053) and m.v_mps == pytest.approx(0.0)


@given(
    st.lists(st.integers(0, 6), max_size=40),
    st.floats(0.0, 20.0),
    st.floats(-50.0, 50.0),
)
def test_wheel_speeds_never_exceed_the_body_limit(channels, speed_gain, turn_gain):
    paper7 = body()
    decode = center_of_activity(
        context(
            "decoding",
            paper7,
            CROSS,
            speed_gain_mps=speed_gain,
            turn_gain_rad_s_per_rad=turn_gain,
            max_speed_mps=10.0,
        )
    )
    m = decode(batch(0, sorted(channels)), W(1))
    assert abs(m.left_mps) <= 0.2 and abs(m.right_mps) <= 0.2
    assert (m.left_mps, m.right_mps) == pytest.approx(
        expected(m.v_mps, m.omega_rad_s, b=0.053), abs=1e-12
    )


def test_wheel_speeds_pass_feasible_commands_unchanged_and_slow_down_to_keep_a_turn():
    b = body(wheel_base_m=0.1, max_wheel_mps=0.2)
    assert wheel_speeds(0.1, 1.0, b) == pytest.approx((0.05, 0.15, 0.1, 1.0))
    assert wheel_speeds(0.3, 2.0, b) == pytest.approx((0.0, 0.2, 0.1, 2.0))
    assert wheel_speeds(-0.5, 0.0, b) == pytest.approx((-0.2, -0.2, -0.2, 0.0))
    assert wheel_speeds(0.0, -10.0, b) == pytest.approx((0.2, -0.2, 0.0, -4.0))


@pytest.mark.parametrize(
    "params, key",
    [
        ({"window_ms": 0.0}, "window_ms"),
        ({"min_speed_mps": -0.1}, "min_speed_mps"),
        ({"min_speed_mps": 0.1, "max_speed_mps": 0.05}, "max_speed_mps"),
        ({"speed_gain_mps": -1.0}, "speed_gain_mps"),
        ({"dead_zone_frac": -0.1}, "dead_zone_frac"),
        ({"turn_gain_rad_s_per_rad": "2"}, "turn_gain_rad_s_per_rad"),
        ({"window": 50.0}, "window"),
        ({"centre_tau_s": -1.0}, "centre_tau_s"),
    ],
)
def test_bad_ca_parameters_are_refused_naming_the_key(params, key):
    with pytest.raises(ConfigError, match=rf"decoding\.params\.{key}\b"):
        center_of_activity(context("decoding", WIDE, CROSS, **params))


# --------------------------------------------------------------------------- two populations

# 4 channels: 0, 1 on the left (x < 0), 2, 3 on the right
HALVES = points([[-300, 0], [-100, 0], [100, 0], [300, 0]])


def two_pop(**params):
    params = {"gain_mps_per_hz": 0.001, "baseline_mps": 0.01, **params}
    return two_population(context("decoding", WIDE, HALVES, **params))


def five_steps(decode, channels_per_step):
    for k in range(5):
        m = decode(batch(k, channels_per_step), W(k + 1))
    return m


def test_crossed_populations_drive_the_opposite_wheels():
    # 2 spikes per step on the left population (2 channels) over 50 ms: 10 spikes / 2 channels
    # / 0.05 s = 100 spikes/s per channel; the right population is silent
    m = five_steps(two_pop(), [0, 1])
    assert (m.left_mps, m.right_mps) == pytest.approx((0.01, 0.01 + 0.001 * 100))
    assert m.omega_rad_s > 0  # activity on the culture's left turns the robot left


def test_uncrossed_populations_drive_their_own_wheels():
    m = five_steps(two_pop(crossed=False), [0, 1])
    assert (m.left_mps, m.right_mps) == pytest.approx((0.11, 0.01))


def test_rates_are_per_channel_and_per_second_over_the_window():
    # 1 spike per step on the right population: 5 spikes / 2 channels / 0.05 s = 50 Hz;
    # 3 per step on the left: 150 Hz
    m = five_steps(two_pop(), [0, 0, 1, 3])
    assert (m.left_mps, m.right_mps) == pytest.approx((0.01 + 0.05, 0.01 + 0.15))


def test_rates_use_the_time_seen_so_far_before_a_full_window():
    m = two_pop()(batch(0, [2, 3]), W(1))  # 2 spikes / 2 channels / 0.01 s = 100 Hz on the right
    assert (m.left_mps, m.right_mps) == pytest.approx((0.11, 0.01))


def test_populations_can_be_listed_by_hand():
    decode = two_pop(left_channels=[0, 3], right_channels=[1])
    m = five_steps(decode, [1])  # 5 spikes / 1 channel / 0.05 s = 100 Hz on the "right"
    assert (m.left_mps, m.right_mps) == pytest.approx((0.11, 0.01))


def test_two_population_wheels_are_clipped():
    paper7 = body()
    decode = two_population(context("decoding", paper7, HALVES, gain_mps_per_hz=1.0))
    m = five_steps(decode, [0, 1, 2, 3])
    assert (m.left_mps, m.right_mps) == pytest.approx((0.2, 0.2))


@pytest.mark.parametrize(
    "params, key",
    [
        ({"left_channels": [0]}, "right_channels"),
        ({"left_channels": [0, 1], "right_channels": [1, 2]}, "left_channels"),
        ({"left_channels": [0, 9], "right_channels": [2]}, "left_channels"),
        ({"left_channels": [], "right_channels": [2]}, "left_channels"),
        ({"crossed": "yes"}, "crossed"),
        ({"window_ms": -5.0}, "window_ms"),
        ({"gain": 1.0}, "gain"),
    ],
)
def test_bad_two_population_parameters_are_refused_naming_the_key(params, key):
    with pytest.raises(ConfigError, match=rf"decoding\.params\.{key}\b"):
        two_population(context("decoding", WIDE, HALVES, **params))


def test_a_culture_with_channels_on_one_side_only_is_refused():
    with pytest.raises(ConfigError, match="one side"):
        two_population(context("decoding", WIDE, points([[0, 0], [0, 100]])))
