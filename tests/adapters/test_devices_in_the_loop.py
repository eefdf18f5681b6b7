"""What the hub does with a real device (``realtime_only``, ``cycle_ms`` in its description)."""

from __future__ import annotations

from tests.harness import harness

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
