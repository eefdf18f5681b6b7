"""What the hub sends each step: the schemes' output, the policy's stand-ins, the limits."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hub.config import load_config
from hub.policy import InputPolicy, SchemeError
from hub.protocol import SensorReading, SpikeBatch
from tests.conftest import TEST_ENDPOINTS
from tests.endpoints import EchoBody, EchoCulture
from tests.windows import RUN, W

BODY = EchoBody().describe()
CULTURE = EchoCulture().describe()


def policy(*overrides, body=BODY, culture=CULTURE, refusals=None) -> InputPolicy:
    cfg = load_config(None, [*TEST_ENDPOINTS, *overrides])
    on_refused = None if refusals is None else (lambda s, why: refusals.append((s, why)))
    return InputPolicy(cfg, body, culture, RUN, on_refused=on_refused)


def spikes(k: int, n: int = 2) -> SpikeBatch:
    return SpikeBatch(**W(k).stamp, channel=np.zeros(n, np.uint32), t_ms=np.zeros(n, np.float32))


def sensors(k: int) -> SensorReading:
    return SensorReading(
        step=k, run=RUN, t_s=W(k).t1_s, ranges_m=[0.5] * 3, pose=[0, 0, 0], contact=False
    )


def test_step_0_stands_still_and_stimulates_nothing():
    p = policy()
    motor, stim = p.motor_for(0, None), p.stim_for(0, None)
    assert motor.window == W(0) and motor.left_mps == motor.right_mps == 0
    assert stim.window == W(0) and stim.n_pulses == 0


def test_each_input_is_the_schemes_output_for_its_window():
    p = policy()
    motor = p.motor_for(5, spikes(4, n=3))  # decode_step: left = the batch's step, right = its size
    assert motor.window == W(5) and (motor.left_mps, motor.right_mps) == (4, 3)
    stim = p.stim_for(5, sensors(4))  # code_step_count: min(step, 8) pulses of amplitude step
    assert stim.window == W(5) and stim.n_pulses == 4 and np.all(stim.amplitude_ua == 4)


def test_missing_spikes_stop_the_robot_or_hold_its_command_as_the_policy_says():
    p = policy()
    p.motor_for(5, spikes(4))
    stopped = p.motor_for(6, None)
    assert stopped.window == W(6) and stopped.left_mps == stopped.right_mps == 0
    p = policy('policy.missing_spikes="hold"')
    moving = p.motor_for(5, spikes(4))
    held = p.motor_for(6, None)
    assert held.window == W(6) and (held.left_mps, held.right_mps) == (
        moving.left_mps,
        moving.right_mps,
    )


def test_missing_sensors_stimulate_nothing_or_code_the_last_reading_again():
    assert policy().stim_for(6, None).n_pulses == 0
    p = policy('policy.missing_sensors="hold"')
    assert p.stim_for(6, None).n_pulses == 0  # nothing to hold yet
    p.stim_for(5, sensors(4))
    again = p.stim_for(6, None)
    assert again.window == W(6) and again.n_pulses == 4


def test_a_decoded_command_over_the_bodys_limit_is_refused_and_the_robot_stops():
    refusals = []
    slow_body = dataclasses.replace(BODY, max_wheel_mps=1.0)
    p = policy(body=slow_body, refusals=refusals)
    motor = p.motor_for(5, spikes(4))  # asks for 4 m/s
    assert motor.left_mps == motor.right_mps == 0
    assert p.refused == {"decoding": 1} and "exceeds max_wheel_mps 1" in refusals[0][1]


def test_a_coded_stimulation_over_the_cultures_limits_is_refused_whole():
    refusals = []
    weak_culture = dataclasses.replace(CULTURE, max_amplitude_ua=3.0)
    p = policy(culture=weak_culture, refusals=refusals)
    assert p.stim_for(3, sensors(2)).n_pulses == 2  # amplitude 2: delivered
    assert p.stim_for(5, sensors(4)).n_pulses == 0  # amplitude 4: nothing, not 3
    assert p.refused == {"coding": 1} and refusals[0][0] == "coding"


def test_a_pulse_exactly_at_the_cultures_limits_is_not_refused():
    """Stimulation's widths and amplitudes are float32: a width asked for exactly at the
    culture's limit (the MEA's 0.8 ms, two 400 µs phases) arrives as 0.80000001 ms and was
    refused as over it. The limit is allowed; the next float32 above it is not."""
    from hub.limits import StimulationLimits
    from hub.protocol import Stimulation

    culture = dataclasses.replace(
        EchoCulture().describe(), max_amplitude_ua=100.0, max_width_ms=0.8
    )
    limits = StimulationLimits(culture)

    def pulse(amplitude_ua, width_ms):
        return Stimulation(
            **W(3).stamp,
            channel=np.zeros(1, np.uint32),
            amplitude_ua=np.full(1, amplitude_ua, np.float32),
            width_ms=np.full(1, width_ms, np.float32),
            onset_ms=np.zeros(1, np.float32),
        )

    assert limits.violation(pulse(100.0, 0.8)) is None
    wider = np.nextafter(np.float32(0.8), np.float32(1.0))
    assert "exceeds max_width_ms" in limits.violation(pulse(100.0, wider))
    stronger = np.nextafter(np.float32(100.0), np.float32(200.0))
    assert "exceeds max_amplitude_ua" in limits.violation(pulse(stronger, 0.8))


def test_a_scheme_that_answers_for_another_step_is_an_error():
    p = policy('coding.scheme="tests.endpoints:code_wrong_step_at_20"')
    p.stim_for(19, sensors(18))
    with pytest.raises(SchemeError, match="for step 20"):
        p.stim_for(20, sensors(19))


def test_a_scheme_that_raises_when_built_is_named_with_what_it_raised(caplog):
    with pytest.raises(SchemeError) as error:
        policy('coding.scheme="tests.endpoints:build_fails"')
    assert str(error.value) == (
        "coding.scheme tests.endpoints:build_fails raised when built: KeyError: 'gain' "
        "(its traceback is logged)"
    )
    assert 'ctx.params["gain"]' in caplog.text  # the scheme's own line, for its author


def test_a_scheme_that_raises_at_a_step_is_named_with_the_step():
    p = policy('decoding.scheme="tests.endpoints:decode_fails_at_3"')
    p.motor_for(2, spikes(1))
    with pytest.raises(SchemeError, match=r"decoding.scheme \S+ raised at step 3: ZeroDivision"):
        p.motor_for(3, spikes(2))
