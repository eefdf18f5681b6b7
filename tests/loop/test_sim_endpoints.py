"""The simulators served on the bus: each sim endpoint with the hub over real Zenoh."""

from __future__ import annotations

import numpy as np
import pytest

from hub.protocol import SensorReading, SpikeBatch
from sim_robot import Arena
from tests.harness import harness

pytestmark = pytest.mark.bus


def test_the_arena_endpoint_drives_the_robot_and_reports_its_sensors(tmp_path, bus_overrides):
    with harness(
        tmp_path,
        bus_overrides,
        'body.kind="sim_robot"',
        'body.params.world="configs/worlds/paper.toml"',
        'decoding.scheme="tests.endpoints:constant_drive"',
        "decoding.params.left_mps=0.1",
        "decoding.params.right_mps=0.1",
        "experiment.duration_s=1.0",
    ) as h:
        result = h.run()
    assert result.outcome == "completed" and result.steps == 100
    desc = result.descriptions["body"]
    world = Arena.from_toml("configs/worlds/paper.toml")
    assert desc.kind == "sim_robot"
    assert np.allclose(desc.sensor_angles_rad, world.body.sensor_angles_rad)
    assert desc.max_range_m == pytest.approx(world.body.max_range_m)
    readings = h.received(SensorReading)
    x0, y0, heading0 = world.pose
    # Step 0 carries zero speed; steps 1..99 drive straight at 0.1 m/s for 10 ms each.
    last = readings[99]
    assert last.t_s == pytest.approx(1.0)
    assert last.pose[0] == pytest.approx(x0 + 0.99 * 0.1 * np.cos(heading0), abs=1e-9)
    assert last.pose[1] == pytest.approx(y0 + 0.99 * 0.1 * np.sin(heading0), abs=1e-9)
    for r in readings.values():
        assert r.ranges_m.size == desc.n_sensors
        assert np.all((r.ranges_m >= 0) & (r.ranges_m <= desc.max_range_m))


def test_the_network_endpoint_answers_a_pulse_with_spikes_in_step_windows(tmp_path, bus_overrides):
    with harness(
        tmp_path,
        bus_overrides,
        'culture.kind="sim_network"',
        "culture.params.seed=3",
        'coding.scheme="tests.endpoints:pulse_at_step"',
        "coding.params.channel=0",
        "coding.params.step=20",
        "experiment.duration_s=0.4",
    ) as h:
        result = h.run()
    assert result.outcome == "completed"
    desc = result.descriptions["culture"]
    assert desc.kind == "sim_network" and desc.channel.size == 1024
    assert set(np.unique(desc.cell_type)) == {0, 1}
    batches = h.received(SpikeBatch)
    assert sorted(batches) == list(range(40))
    for k, b in batches.items():
        assert b.t0_s == pytest.approx(k * 0.01) and b.t1_s == pytest.approx((k + 1) * 0.01)
        assert np.all((b.t_ms >= 0) & (b.t_ms <= 10.0))
    # 100 µA for 10 ms makes the stimulated neuron fire during that step.
    assert 0 in batches[20].channel


def test_warming_up_the_network_endpoint_leaves_its_state_as_it_was():
    from hub.config import load_config
    from sim_network.endpoint import NetworkEndpoint

    cfg = load_config(None, ["culture.params.seed=4"])
    warmed = NetworkEndpoint.from_config(cfg.culture, cfg)
    cold = NetworkEndpoint.from_config(cfg.culture, cfg)
    warmed.warm_up()
    a, b = warmed.net.run(200.0), cold.net.run(200.0)
    assert np.array_equal(a.channel, b.channel) and np.array_equal(a.t_ms, b.t_ms)
