"""The summary beside a run: behaviour of any body from its poses, a raster of its spikes."""

import json

import pytest

from hub.protocol import SensorReading, SpikeBatch
from hub.record import Recorder, write_manifest
from lab.postrun import SUMMARY_FILE, summarize_run
from tests.windows import RUN


def test_a_real_body_gets_path_metrics_and_late_batches_still_make_a_raster(tmp_path):
    config = {"loop": {"period_ms": 10.0}, "body": {"kind": "khepera", "params": {}}}
    write_manifest(tmp_path, {"name": "real", "seed": 1, "config": config, "steps": 3})
    rec = Recorder(tmp_path)
    for k in (0, 2, 1):  # step 1's batch was late: recorded after step 2's
        batch = SpikeBatch(
            step=k, run=RUN, t0_s=k * 0.01, t1_s=(k + 1) * 0.01, channel=[0, 1], t_ms=[1.0, 2.0]
        )
        rec.message("rx", "nv/s/culture/0/spikes", batch.encode())
    for k in range(3):
        reading = SensorReading(
            step=k,
            run=RUN,
            t_s=(k + 1) * 0.01,
            ranges_m=[0.1],
            pose=[0.01 * k, 0.0, 0.0],
            contact=False,
        )
        rec.message("rx", "nv/s/body/0/sensors", reading.encode())
    rec.close()

    summary = summarize_run(tmp_path)

    assert json.loads((tmp_path / SUMMARY_FILE).read_text()) == summary
    assert summary["spikes"] == 6
    assert "raster.png" in summary["figures"]
    assert summary["behaviour"]["distance_m"] == pytest.approx(0.02)
    assert "obstacle_entries" not in summary["behaviour"]  # no world known
    assert not any(f.startswith("trajectory") for f in summary["figures"])
