"""Coding schemes: which channels are pulsed, how hard and when, for hand-made sensor readings."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hub.coding import CultureFrame, rate, somatotopic, somatotopic_inverse, stimulation_sites
from hub.protocol import SensorReading, StepWindow, Stimulation
from hub.schemes import ConfigError
from tests.schemes.descriptions import PAPER7_DEG, body, context, grid, points

MAX_RANGE_M = 0.25
PERIOD_S = 0.01
RUN = "0" * 32


def W(step: int) -> StepWindow:
    """The window of ``step`` in the test run."""
    return StepWindow.of(RUN, step, PERIOD_S)


def reading(ranges_m, step: int = 0) -> SensorReading:
    return SensorReading(
        step=step,
        run=RUN,
        t_s=W(step).t1_s,
        ranges_m=np.asarray(ranges_m, dtype=np.float32),
        pose=[0.0, 0.0, 0.0],
        contact=False,
    )


def nothing_seen(n: int = 7) -> SensorReading:
    return reading(np.full(n, MAX_RANGE_M))


def body_angle_of(culture, channel) -> np.ndarray:
    """Body angle (CCW from forward) of channels as placed on the culture (+y forward, −x left)."""
    frame = CultureFrame.of(culture)
    dx = culture.x_um[channel] - frame.centre_x_um
    dy = culture.y_um[channel] - frame.centre_y_um
    return np.arctan2(-dx, dy)


# --------------------------------------------------------------------------- geometry


def test_culture_frame_is_the_middle_and_half_side_of_the_layout():
    frame = CultureFrame.of(grid(32, 50.0))  # positions 25 … 1575 µm
    assert (frame.centre_x_um, frame.centre_y_um, frame.radius_um) == (800.0, 800.0, 775.0)


def test_forward_is_plus_y_and_left_is_minus_x():
    frame = CultureFrame.of(grid())
    assert frame.point_at(0.0, 100.0) == pytest.approx((800.0, 900.0))
    assert frame.point_at(math.pi / 2, 100.0) == pytest.approx((700.0, 800.0))
    assert frame.point_at(-math.pi / 2, 100.0) == pytest.approx((900.0, 800.0))


def test_somatotopic_sites_lie_at_the_sensor_angles_on_the_site_circle():
    culture = grid()
    sites = stimulation_sites(context(culture_desc=culture))
    assert len(sites) == 7 and all(s.size == 1 for s in sites)
    ch = np.concatenate(sites)
    # within half a grid cell (at 465 µm from the centre: ~0.06 rad) of the sensor's angle
    np.testing.assert_allclose(body_angle_of(culture, ch), np.deg2rad(PAPER7_DEG), atol=0.06)
    frame = CultureFrame.of(culture)
    dist = np.hypot(culture.x_um[ch] - 800.0, culture.y_um[ch] - 800.0)
    np.testing.assert_allclose(dist, 0.6 * frame.radius_um, atol=50.0 / math.sqrt(2))


def test_site_radius_is_configurable():
    culture = grid()
    ch = np.concatenate(stimulation_sites(context(culture_desc=culture, site_radius_frac=0.0)))
    # at the centre: the 7 channels nearest to (800, 800), all distinct
    assert np.unique(ch).size == 7
    assert np.hypot(culture.x_um[ch] - 800, culture.y_um[ch] - 800).max() < 80.0


def test_four_adjacent_sites_per_sensor_are_nearest_and_not_shared():
    culture = grid()
    sites = stimulation_sites(context(culture_desc=culture, sites_per_sensor=4))
    assert all(s.size == 4 for s in sites)
    all_ch = np.concatenate(sites)
    assert np.unique(all_ch).size == 28
    for s in sites:  # a compact 2 × 2 block: every pair within one diagonal of the grid
        x, y = culture.x_um[s], culture.y_um[s]
        assert np.ptp(x) <= 50.0 and np.ptp(y) <= 50.0


def test_sites_are_excitatory_when_the_culture_reports_cell_types():
    culture = grid(inhibitory_every=2)  # every other neuron inhibitory
    ch = np.concatenate(stimulation_sites(context(culture_desc=culture, sites_per_sensor=4)))
    assert (culture.cell_type[ch] == 0).all()
    anything = np.concatenate(
        stimulation_sites(context(culture_desc=culture, sites_per_sensor=4, excitatory_only=False))
    )
    assert (culture.cell_type[anything] == 1).any()


def test_sites_listed_by_hand_are_used_as_given():
    channels = [[5], 7, [9, 10], 11, 12, 13, 14]
    sites = stimulation_sites(context(channels=channels))
    assert [s.tolist() for s in sites] == [[5], [7], [9, 10], [11], [12], [13], [14]]


@pytest.mark.parametrize(
    "channels, reason",
    [
        ([1, 2, 3], "one entry per sensor"),
        ([1, 2, 3, 4, 5, 6, 5000], "not one of the culture's"),
        ([1, 2, 3, 4, 5, 6, 1], "listed for two sensors"),
        ([1, 2, 3, 4, 5, 6, []], "non-empty list"),
        ([1, 2, 3, 4, 5, 6, "x"], "channel id"),
    ],
)
def test_bad_hand_listed_sites_are_refused_naming_the_key(channels, reason):
    with pytest.raises(ConfigError, match=rf"coding\.params\.channels.*{reason}"):
        somatotopic(context(channels=channels))


def test_more_sites_than_channels_is_refused():
    culture = points([[0, 0], [10, 0], [20, 0]])
    with pytest.raises(ConfigError, match=r"coding\.params\.sites_per_sensor"):
        somatotopic(context(culture_desc=culture))


def test_khepera_like_sensors_facing_the_same_way_get_distinct_sites():
    sites = stimulation_sites(context(body_desc=body([0.0, 0.0, 180.0, 180.0])))
    assert np.unique(np.concatenate(sites)).size == 4


# --------------------------------------------------------------------------- amplitude codes


def test_somatotopic_amplitude_is_gain_times_distance_on_each_sensors_site():
    ctx = context(channels=[10, 11, 12, 13, 14, 15, 16])
    code = somatotopic(ctx)
    stim = code(reading([0.25, 0.2, 0.1, 0.05, 0.0, 0.125, 0.25]), W(3))
    # default gain 100 µA / 0.25 m = 400 µA/m; 0 m → 0 µA, under the 20 µA minimum: no pulse
    assert stim.step == 3
    assert stim.channel.tolist() == [10, 11, 12, 13, 15, 16]
    np.testing.assert_allclose(stim.amplitude_ua, [100, 80, 40, 20, 50, 100], rtol=1e-6)
    assert (stim.width_ms == 10.0).all() and (stim.onset_ms == 0.0).all()


def test_every_site_of_a_sensor_gets_its_sensors_amplitude():
    code = somatotopic(context(sites_per_sensor=4))
    stim = code(reading([0.25, 0, 0, 0, 0, 0, 0.125]), W(1))
    assert stim.n_pulses == 8
    np.testing.assert_allclose(np.sort(stim.amplitude_ua), [50] * 4 + [100] * 4, rtol=1e-6)


def test_amplitude_is_clamped_to_the_maximum():
    code = somatotopic(context(gain_ua_per_m=1000.0, max_amplitude_ua=150.0))
    stim = code(reading([0.25, 0.1, 0.05, 0.01, 0.01, 0.01, 0.01]), W(1))
    np.testing.assert_allclose(stim.amplitude_ua, [150, 100, 50], rtol=1e-6)


def test_pulses_weaker_than_the_minimum_are_not_sent():
    code = somatotopic(context(min_amplitude_ua=25.0))
    # 0.0625 m → exactly 25 µA (sent: the minimum itself is allowed); 0.06 m → 24 µA (not)
    stim = code(reading([0.25, 0.2, 0.0625, 0.06, 0.01, 0.0, 0.0]), W(1))
    np.testing.assert_allclose(stim.amplitude_ua, [100, 80, 25], rtol=1e-6)


def test_inverse_code_is_stronger_for_nearer_obstacles_and_silent_when_nothing_is_seen():
    code = somatotopic_inverse(context(channels=[10, 11, 12, 13, 14, 15, 16]))
    stim = code(reading([0.0, 0.05, 0.125, 0.1875, 0.24, 0.25, 0.25]), W(2))
    assert stim.channel.tolist() == [10, 11, 12, 13]
    np.testing.assert_allclose(stim.amplitude_ua, [100, 80, 50, 25], rtol=1e-6)
    assert code(nothing_seen(), W(3)).n_pulses == 0


def test_ranges_beyond_max_range_count_as_max_range():
    code = somatotopic(context(channels=[10, 11, 12, 13, 14, 15, 16]))
    stim = code(reading([0.3] + [0.25] * 6), W(1))
    np.testing.assert_allclose(stim.amplitude_ua, [100] * 7, rtol=1e-6)


def test_pulse_period_spaces_pulses_over_steps_on_a_fixed_grid():
    code = somatotopic(context(pulse_period_ms=25.0, channels=[0, 1, 2, 3, 4, 5, 6]))
    times = []
    for step in range(12):
        stim = code(nothing_seen(), W(step))
        assert stim.n_pulses in (0, 7)
        times += [step * 10.0 + t for t in np.unique(stim.onset_ms)]
    np.testing.assert_allclose(times, [0, 25, 50, 75, 100])


def test_default_is_one_pulse_per_site_every_step():
    code = somatotopic(context())
    assert [code(nothing_seen(), W(k)).n_pulses for k in range(5)] == [7] * 5


def test_a_coder_output_is_a_valid_message():
    stim = somatotopic(context(sites_per_sensor=4))(nothing_seen(), W(9))
    assert Stimulation.decode(stim.encode()) == stim


def test_a_reading_with_the_wrong_number_of_ranges_is_an_error():
    code = somatotopic(context())
    with pytest.raises(ValueError, match="3 ranges, the body described 7"):
        code(reading([0.1, 0.1, 0.1]), W(1))


@pytest.mark.parametrize(
    "params, key",
    [
        ({"gain": 3.0}, "gain"),
        ({"width_ms": 0.0}, "width_ms"),
        ({"width_ms": "10"}, "width_ms"),
        ({"max_amplitude_ua": -1.0}, "max_amplitude_ua"),
        ({"min_amplitude_ua": 200.0}, "min_amplitude_ua"),
        ({"pulse_period_ms": 5.0}, "pulse_period_ms"),  # shorter than the 10 ms width
        ({"site_radius_frac": 1.5}, "site_radius_frac"),
        ({"sites_per_sensor": 0}, "sites_per_sensor"),
        ({"sites_per_sensor": 2.0}, "sites_per_sensor"),
        ({"gain_ua_per_m": -1.0}, "gain_ua_per_m"),
        ({"excitatory_only": 1}, "excitatory_only"),
    ],
)
def test_bad_parameters_are_refused_naming_the_key(params, key):
    with pytest.raises(ConfigError, match=rf"coding\.params\.{key}\b"):
        somatotopic(context(**params))


# --------------------------------------------------------------------------- rate code


def run_rate(code, ranges_per_step):
    """Absolute pulse times (ms) per channel over consecutive steps."""
    times: dict[int, list[float]] = {}
    for step, ranges in enumerate(ranges_per_step):
        stim = code(reading(ranges, step), W(step))
        assert ((stim.onset_ms >= 0) & (stim.onset_ms < 10.0)).all()
        for c, t in zip(stim.channel.tolist(), stim.onset_ms.tolist(), strict=True):
            times.setdefault(c, []).append(step * 10.0 + t)
    return times


def test_rate_code_pulses_at_exact_times_for_a_constant_distance():
    code = rate(context(channels=[0, 1, 2, 3, 4, 5, 6], min_rate_hz=0.0, max_rate_hz=20.0))
    # sensor 0 touching (20 Hz), sensor 1 at half range (10 Hz), sensor 2 at 3/4 (5 Hz)
    ranges = [0.0, 0.125, 0.1875, 0.25, 0.25, 0.25, 0.25]
    times = run_rate(code, [ranges] * 100)  # 1 s
    np.testing.assert_allclose(times[0], np.arange(0, 1000, 50.0), atol=1e-3)
    np.testing.assert_allclose(times[1], np.arange(0, 1000, 100.0), atol=1e-3)
    np.testing.assert_allclose(times[2], np.arange(0, 1000, 200.0), atol=1e-3)
    assert set(times) == {0, 1, 2}  # nothing in range at min_rate_hz = 0: no pulses


def test_rate_code_uses_a_fixed_clamped_amplitude_and_the_width():
    code = rate(context(amplitude_ua=300.0, max_amplitude_ua=120.0, width_ms=5.0))
    stim = code(reading([0.0] * 7), W(1))
    assert stim.n_pulses == 7
    assert (stim.amplitude_ua == 120.0).all() and (stim.width_ms == 5.0).all()


def test_rate_code_keeps_its_phase_so_the_count_follows_the_rate_over_time():
    rng = np.random.default_rng(4)
    code = rate(context(channels=[0, 1, 2, 3, 4, 5, 6], min_rate_hz=2.0, max_rate_hz=47.0))
    ranges = rng.uniform(0.0, 0.25, size=(700, 7))
    # distances that change every step, with rates that do not divide the 10 ms step
    times = run_rate(code, ranges)
    sent = ranges.astype(np.float32).astype(np.float64)  # what the reading carries
    hz = 2.0 + 45.0 * (1.0 - sent / 0.25)
    integral = hz.sum(axis=0) * 0.01  # ∫ f dt over the 7 s
    counts = np.array([len(times[c]) for c in range(7)])
    # the first pulse at t = 0, then one each time the phase gains a whole cycle
    np.testing.assert_array_equal(counts, np.floor(integral) + 1)
    for c in range(7):  # successive pulses never closer than the highest rate allows
        assert np.diff(times[c]).min() >= 1000.0 / 47.0 - 1e-6


def test_rate_code_is_higher_for_nearer_obstacles():
    code = rate(context(channels=[0, 1, 2, 3, 4, 5, 6], min_rate_hz=1.0, max_rate_hz=40.0))
    times = run_rate(code, [[0.02, 0.08, 0.14, 0.2, 0.25, 0.25, 0.25]] * 200)
    counts = [len(times[c]) for c in range(7)]
    assert counts[0] > counts[1] > counts[2] > counts[3] > counts[4] == counts[5] == counts[6] > 0


@pytest.mark.parametrize(
    "params, key",
    [
        ({"max_rate_hz": 150.0}, "max_rate_hz"),  # over 1000 / 10 ms
        ({"min_rate_hz": 30.0, "max_rate_hz": 20.0}, "max_rate_hz"),
        ({"min_rate_hz": -1.0}, "min_rate_hz"),
        ({"amplitude_ua": 0.0}, "amplitude_ua"),
        ({"gain_ua_per_m": 3.0}, "gain_ua_per_m"),  # an amplitude-code parameter
    ],
)
def test_bad_rate_parameters_are_refused_naming_the_key(params, key):
    with pytest.raises(ConfigError, match=rf"coding\.params\.{key}\b"):
        rate(context(**params))
