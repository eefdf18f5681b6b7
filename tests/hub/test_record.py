"""The run record: append-only, readable after a kill, typed views for analysis."""

import json

import numpy as np

from hub.protocol import SensorReading, SpikeBatch
from hub.record import RECORD_FILE, Recorder, iter_frames, new_run_dir, read_run, write_manifest


def _reading(k):
    return SensorReading(step=k, t_s=k * 0.01, ranges_m=[0.2], pose=[k, 0, 0], contact=False)


def test_messages_and_events_read_back_in_order(tmp_path):
    rec = Recorder(tmp_path)
    for k in range(3):
        rec.message("rx", "nv/s/body/0/sensors", _reading(k).encode())
    rec.event("dropped", role="body", kind="stale")
    rec.message("drop", "nv/s/body/0/sensors", b"\x00garbage")
    rec.message("drop", "nv/s/body/0/sensors", _reading(99).encode())  # e.g. a duplicate
    rec.message("late", "nv/s/body/0/sensors", _reading(3).encode())
    rec.close()
    frames = list(iter_frames(tmp_path / RECORD_FILE))
    assert [f.direction for f in frames] == ["rx", "rx", "rx", "ev", "drop", "drop", "late"]
    assert frames[3].key == "dropped" and frames[3].payload == {"role": "body", "kind": "stale"}
    run = read_run(tmp_path)
    t_s, poses = run.trajectory()
    # Dropped frames are kept in the record but are not the body's trajectory; late ones are.
    assert np.array_equal(poses[:, 0], [0, 1, 2, 3])
    assert np.allclose(t_s, [0, 0.01, 0.02, 0.03])


def test_a_truncated_or_damaged_tail_reads_up_to_the_last_whole_frame(tmp_path):
    rec = Recorder(tmp_path)
    for k in range(10):
        rec.message("rx", "nv/s/body/0/sensors", _reading(k).encode())
    rec.close()
    path = tmp_path / RECORD_FILE
    whole = path.read_bytes()
    path.write_bytes(whole[:-7])  # killed mid-write
    assert len(list(iter_frames(path))) == 9
    path.write_bytes(whole + b"\xc1\xc1\xc1")  # never-valid msgpack bytes at the end
    assert len(list(iter_frames(path))) == 10


def test_the_writer_flushes_at_the_first_tick_its_period_after_the_last_flush(tmp_path):
    rec = Recorder(tmp_path, flush_s=0.0)  # flush at every tick
    rec.message("tx", "nv/s/body/0/motor", b"x")
    rec.tick()  # the hub ticks at least every flush_s
    # Another reader sees the frame while the recorder is still open.
    assert len(list(iter_frames(tmp_path / RECORD_FILE))) == 1
    rec.close()


def test_spikes_are_returned_in_absolute_time(tmp_path):
    rec = Recorder(tmp_path)
    for k in range(2):
        batch = SpikeBatch(step=k, t0_s=k * 0.01, t1_s=(k + 1) * 0.01, channel=[k], t_ms=[2.5])
        rec.message("rx", "nv/s/culture/0/spikes", batch.encode())
    rec.close()
    channel, t_ms = read_run(tmp_path).spikes()
    assert list(channel) == [0, 1]
    assert np.allclose(t_ms, [2.5, 12.5])


def test_run_folders_are_unique_and_manifests_atomic(tmp_path):
    a = new_run_dir(tmp_path, "exp")
    b = new_run_dir(tmp_path, "exp")
    assert a != b and a.is_dir() and b.is_dir()
    write_manifest(a, {"outcome": "running", "x": np.float32(1.5)})
    assert json.loads((a / "manifest.json").read_text()) == {"outcome": "running", "x": 1.5}
    assert read_run(b).frames == [] and read_run(b).manifest == {}
