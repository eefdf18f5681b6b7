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


def _small_run(run_dir, steps_in_order, events=()):
    run_dir.mkdir(parents=True, exist_ok=True)
    config = {"loop": {"period_ms": 10.0}, "body": {"kind": "khepera", "params": {}}}
    write_manifest(run_dir, {"name": "r", "seed": 1, "config": config, "steps": 3,
                             "outcome": "completed"})  # fmt: skip
    rec = Recorder(run_dir)
    for k in steps_in_order:
        batch = SpikeBatch(
            step=k, run=RUN, t0_s=k * 0.01, t1_s=(k + 1) * 0.01, channel=[k], t_ms=[1.0]
        )
        rec.message("rx", "nv/s/culture/0/spikes", batch.encode())
        reading = SensorReading(step=k, run=RUN, t_s=(k + 1) * 0.01, ranges_m=[0.1],
                                pose=[0.01 * k, 0.0, 0.0], contact=False)  # fmt: skip
        rec.message("rx", "nv/s/body/0/sensors", reading.encode())
    for name, details in events:
        rec.event(name, **details)
    rec.close()


def test_the_raster_shades_the_network_bursts_the_observer_reported(tmp_path):
    from hub.record import read_run
    from lab.postrun import recorded_network_bursts

    _small_run(tmp_path / "off", (0, 1, 2))
    assert recorded_network_bursts(read_run(tmp_path / "off")) is None  # none reported
    _small_run(tmp_path / "on", (0, 1, 2), events=[
        ("network_burst", {"start_ms": 12.0, "end_ms": 25.0, "n_channels": 3,
                           "core_start_ms": 14.0, "core_end_ms": 20.0, "at_step": 3}),
        ("network_burst", {"start_ms": 1.0, "end_ms": 9.0, "n_channels": 3, "at_step": 1}),
    ])  # fmt: skip
    bursts = recorded_network_bursts(read_run(tmp_path / "on"))
    assert bursts.start_ms.tolist() == [1.0, 12.0] and bursts.end_ms.tolist() == [9.0, 25.0]
    # the second, from an older record, has no core: its extent stands for it
    assert bursts.core_start_ms.tolist() == [1.0, 14.0]
    assert bursts.core_end_ms.tolist() == [9.0, 20.0]
    assert "raster.png" in summarize_run(tmp_path / "on")["figures"]


def test_the_reader_gives_spikes_and_poses_in_order_whatever_the_records_order(tmp_path):
    from hub.record import read_run

    _small_run(tmp_path, (1, 0, 2))
    rec = read_run(tmp_path)
    channel, t_ms = rec.spikes()
    assert channel.tolist() == [0, 1, 2] and t_ms.tolist() == [1.0, 11.0, 21.0]
    t_s, poses = rec.trajectory()
    assert t_s.tolist() == [0.01, 0.02, 0.03] and poses[:, 0].tolist() == [0.0, 0.01, 0.02]


def test_a_failing_figure_is_named_and_the_summary_is_still_written(tmp_path, monkeypatch):
    import lab.postrun

    def broken(*args, **kwargs):
        raise RuntimeError("no fonts today")

    monkeypatch.setattr(lab.postrun, "plot_raster", broken)
    _small_run(tmp_path, (0, 1, 2))
    summary = summarize_run(tmp_path)
    assert summary["failures"] == [{"part": "raster", "error": "RuntimeError: no fonts today"}]
    assert summary["spikes"] == 3 and summary["behaviour"]["distance_m"] == pytest.approx(0.02)
    assert json.loads((tmp_path / SUMMARY_FILE).read_text()) == summary
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["postrun_failures"] == summary["failures"]
    assert manifest["outcome"] == "completed"  # the run itself is untouched
