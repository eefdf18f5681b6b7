"""A small recorded run written by hand, for the replay's tests (no bus, no simulator)."""

from __future__ import annotations

import numpy as np

from hub.protocol import Description, MotorCommand, SensorReading, SpikeBatch, Stimulation
from hub.record import Recorder, write_manifest
from tests.windows import RUN, W

N_STEPS = 200
PERIOD_MS = 10.0


def pose(k: int) -> list[float]:
    """The body's pose after step ``k``: 1 mm a step along x."""
    return [0.001 * k, 0.0, 0.5]


BURST = {"start_ms": 500.0, "end_ms": 560.0, "n_channels": 3, "core_start_ms": 520.0,
         "core_end_ms": 530.0}  # fmt: skip


def write_run(
    run_dir,
    *,
    steps: int = N_STEPS,
    bursts: tuple[dict, ...] = (BURST,),
    spike_channel=lambda k: k % 4,
) -> None:
    """A closed loop of ``steps`` steps: a reading, a spike (5 ms into step ``k``, on
    ``spike_channel(k)``), a pulse and a command a step, ``bursts`` (a network burst at
    500-560 ms), a late body reply (step 50) and a missing culture reply (step 70)."""
    run_dir.mkdir(parents=True, exist_ok=True)
    rec = Recorder(run_dir)
    body = Description(
        role="body",
        id="0",
        kind="sim_robot",
        sensor_angles_rad=[-0.5, 0.0, 0.5],
        max_range_m=0.25,
        wheel_base_m=0.05,
        radius_m=0.035,
        max_wheel_mps=0.2,
    )
    culture = Description(
        role="culture",
        id="0",
        kind="test",
        channel=np.arange(4),
        x_um=[0.0, 100.0, 0.0, 100.0],
        y_um=[0.0, 0.0, 100.0, 100.0],
        cell_type=np.array([0, 0, 0, 1], np.uint8),
    )
    rec.message("rx", "nv/s/body/0/describe", body.encode())
    rec.message("rx", "nv/s/culture/0/describe", culture.encode())
    for k in range(steps):
        window = W(k)
        rec.message(
            "tx",
            "nv/s/body/0/motor",
            MotorCommand(**window.stamp, left_mps=0.1, right_mps=0.1).encode(),
        )
        stim = Stimulation(
            **window.stamp, channel=[k % 4], amplitude_ua=[5.0], width_ms=[0.2], onset_ms=[0.0]
        )
        rec.message("tx", "nv/s/culture/0/stim", stim.encode())
        reading = SensorReading(
            step=k,
            run=RUN,
            t_s=window.t1_s,
            ranges_m=[0.25, 0.1, 0.25],
            pose=pose(k),
            contact=False,
        )
        rec.message("late" if k == 50 else "rx", "nv/s/body/0/sensors", reading.encode())
        if k != 70:
            spikes = SpikeBatch(**window.stamp, channel=[spike_channel(k)], t_ms=[5.0])
            rec.message("rx", "nv/s/culture/0/spikes", spikes.encode())
    for burst in bursts:
        rec.event("network_burst", **burst, at_step=int(burst["end_ms"] // PERIOD_MS) + 1)
    rec.event("late", role="body", step=50, at_step=52)
    rec.event("missed", role="culture", step=70)
    rec.close()
    write_manifest(
        run_dir,
        {
            "format": "neuvision-run",
            "v": 1,
            "name": "synthetic",
            "run_id": RUN,
            "config": {
                "experiment": {"name": "synthetic", "duration_s": steps * PERIOD_MS / 1e3},
                "loop": {"period_ms": PERIOD_MS, "mode": "lockstep"},
                "body": {"id": "0", "kind": "sim_robot", "params": {}},
                "culture": {"id": "0", "kind": "test", "params": {}},
            },
            "outcome": "completed",
            "steps": steps,
            "timing": {"x_realtime": 12.5, "late_steps": 1},
            "counts": {"dropped": {"body": {"stale": 2}}},
            "endpoints": {"body": {"kind": "sim_robot", "id": "0", "steps": steps}},
        },
    )
