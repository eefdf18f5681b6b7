"""What the hub does with a real device (``realtime_only``, ``cycle_ms`` in its description)."""

from __future__ import annotations

from tests.harness import harness
from tests.stall_witness import StallWitness

DEVICE = 'body.kind="tests.endpoints:DeviceBody"'


def test_the_hub_refuses_a_lockstep_run_with_a_device(tmp_path, bus_overrides):
    with harness(tmp_path, bus_overrides, DEVICE, 'loop.mode="lockstep"') as h:
        result = h.run()
    assert result.outcome == "fault"
    assert "body/0 (test_device_body) is a real device" in result.reason
    assert "realtime" in result.reason
    faults = [e.payload for e in h.record.events if e.key == "fault"]  # recorded
    assert len(faults) == 1 and "is a real device" in faults[0]["reason"]


def test_the_hub_warns_when_the_period_is_shorter_than_the_devices_cycle(tmp_path, bus_overrides):
    with harness(
        tmp_path, bus_overrides, DEVICE, 'loop.mode="realtime"', "loop.period_ms=50",
        "experiment.duration_s=0.2",
    ) as h:  # fmt: skip
        result = h.run()
    assert result.outcome == "completed"
    warnings = [e.payload for e in h.record.events if e.key == "warning"]
    assert len(warnings) == 1
    assert "80.0 ms, longer than the period of 50 ms" in warnings[0]["reason"]


TRAILING = 'culture.kind="tests.endpoints:TrailingCulture"'


def test_a_culture_answering_after_its_window_needs_a_deadline_between_one_and_two_periods(
    tmp_path, bus_overrides
):
    with harness(tmp_path, bus_overrides, TRAILING, 'loop.mode="realtime"') as h:
        result = h.run()
    assert result.outcome == "fault"
    assert "answers each window after it has passed" in result.reason
    assert "loop.deadline_ms must lie between one and two periods" in result.reason


def test_its_reply_trails_by_a_step_and_the_loop_keeps_time(tmp_path, bus_overrides):
    from hub.protocol import MotorCommand

    with StallWitness() as witness, harness(
        tmp_path, bus_overrides, TRAILING, 'loop.mode="realtime"', "loop.period_ms=10",
        "loop.deadline_ms=18", "experiment.duration_s=0.5",
    ) as h:  # fmt: skip
        result = h.run()
    assert result.outcome == "completed" and result.steps == 50
    # none late, but where the host held a CPU (tests/stall_witness.py)
    excused = witness.explains_every_miss(h.record)
    assert result.timing["late_steps"] == 0 or excused, (result.timing, witness.summary())
    assert result.counts["missing"] == {} or excused
    motors = h.sent(MotorCommand)
    # the motor command of step k is decoded from the spikes of step k-2: two steps of latency
    assert [motors[k].left_mps for k in range(2, 50)] == [float(k - 2) for k in range(2, 50)]
