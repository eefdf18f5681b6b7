"""The run record: append-only, readable after a kill, typed views for analysis."""

import errno
import hashlib
import json
import socket
import subprocess
import sys
from pathlib import Path

import msgpack
import numpy as np
import pytest

from hub.protocol import SensorReading, SpikeBatch
from hub.record import (
    DROP_HEAD_BYTES,
    RECORD_FILE,
    RESERVE_BYTES,
    RESERVE_FILE,
    Dropped,
    Recorder,
    host,
    iter_frames,
    new_run_dir,
    read_run,
    write_manifest,
)
from tests.windows import RUN


def _reading(k):
    return SensorReading(
        step=k, run=RUN, t_s=k * 0.01, ranges_m=[0.2], pose=[k, 0, 0], contact=False
    )


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


@pytest.mark.parametrize(
    "damage",
    [
        lambda frame: b"\xc1" + frame[1:],  # a byte never valid in msgpack, at its start
        # the payload's length (after the time, the direction and the 19-byte key) made
        # one that runs past the end of the file
        lambda frame: (
            frame[:33] + b"\xc6\x7f\xff\xff\xff" + frame[33 + {0xC4: 2, 0xC5: 3}[frame[33]] :]
        ),
    ],
    ids=["unreadable", "length past the end"],
)
def test_a_damaged_frame_is_skipped_and_the_frames_after_it_read(tmp_path, damage):
    rec = Recorder(tmp_path)
    for k in range(10):
        rec.message("rx", "nv/s/body/0/sensors", _reading(k).encode())
    rec.close()
    path = tmp_path / RECORD_FILE
    whole = path.read_bytes()
    starts = [i for i in range(len(whole)) if whole.startswith(b"\x94\xcf", i)]
    assert len(starts) == 10
    fifth = damage(whole[starts[4] : starts[5]])
    path.write_bytes(whole[: starts[4]] + fifth + whole[starts[5] :])
    run = read_run(tmp_path)
    assert [r.step for r in run.decoded(SensorReading)] == [0, 1, 2, 3, 5, 6, 7, 8, 9]
    assert run.skipped == [(starts[4], len(fifth))]
    assert f"{len(fifth)} bytes of the record file could not be read" in run.damage_note()


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
        batch = SpikeBatch(
            step=k, run=RUN, t0_s=k * 0.01, t1_s=(k + 1) * 0.01, channel=[k], t_ms=[2.5]
        )
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


def test_a_disk_filled_during_the_run_still_takes_the_manifest_that_ends_it(tmp_path, monkeypatch):
    write_manifest(tmp_path, {"outcome": "running"})
    reserve = tmp_path / RESERVE_FILE
    assert reserve.stat().st_size == RESERVE_BYTES
    write_bytes = Path.write_bytes

    def full_while_reserved(path, data):
        if reserve.exists():  # the record took the rest of the disk
            raise OSError(errno.ENOSPC, "No space left on device")
        write_bytes(path, data)

    monkeypatch.setattr(Path, "write_bytes", full_while_reserved)
    write_manifest(tmp_path, {"outcome": "fault", "reason": "No space left on device"})
    assert json.loads((tmp_path / "manifest.json").read_text())["outcome"] == "fault"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["manifest.json"]


def test_a_manifest_write_that_fails_leaves_the_manifest_as_it_was_and_no_stray_file(
    tmp_path, monkeypatch
):
    write_manifest(tmp_path, {"outcome": "running"})
    write_bytes = Path.write_bytes

    def full_disk(path, data):
        write_bytes(path, data[:10])  # some of it, then no room
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_bytes", full_disk)
    with pytest.raises(OSError, match="No space left"):
        write_manifest(tmp_path, {"outcome": "completed"})
    monkeypatch.undo()
    assert json.loads((tmp_path / "manifest.json").read_text()) == {"outcome": "running"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["manifest.json"]


def test_a_dropped_payload_is_stored_as_its_head_length_and_digest_never_as_a_message(tmp_path):
    rec = Recorder(tmp_path)
    fake = _reading(7).encode()  # well formed, but dropped (e.g. foreign)
    rec.message("drop", "nv/s/body/0/sensors", fake)
    rec.message("rx", "nv/s/body/0/sensors", _reading(1).encode())
    rec.close()
    run = read_run(tmp_path)
    (drop,) = run.drops
    assert isinstance(drop.payload, Dropped)
    assert drop.payload.head == fake[:DROP_HEAD_BYTES] and drop.payload.n_bytes == len(fake)
    assert drop.payload.blake2b == hashlib.blake2b(fake, digest_size=16).digest()
    assert drop.payload.matches(fake) and not drop.payload.matches(fake + b"x")
    # Asked for every direction, the typed view still gives only real messages.
    assert [r.step for r in run.decoded(SensorReading)] == [1]


def test_10000_dropped_50_kb_payloads_leave_a_small_record_and_the_messages_intact(tmp_path):
    rng = np.random.default_rng(0)
    junk = [rng.bytes(50_000) for _ in range(4)]
    budget = 256 << 10
    rec = Recorder(tmp_path, drop_budget_bytes=budget)
    batches = []
    for k in range(10_000):
        rec.message("drop", "nv/s/culture/0/spikes", junk[k % 4])
        if k % 1000 == 0:
            batch = SpikeBatch(
                step=k, run=RUN, t0_s=k * 0.01, t1_s=(k + 1) * 0.01, channel=[k % 7], t_ms=[1.5]
            )
            batches.append(batch)
            rec.message("rx", "nv/s/culture/0/spikes", batch.encode())
        if k % 100 == 0:
            rec.tick()
    rec.close()
    size = (tmp_path / RECORD_FILE).stat().st_size
    assert size < budget + (64 << 10)  # 500 MB of drops: the record holds a quarter MB
    run = read_run(tmp_path)
    assert run.decoded(SpikeBatch, "rx") == batches
    stored = [f.payload for f in run.drops]
    assert 0 < len(stored) < 10_000
    assert all(d.n_bytes == 50_000 and d.matches(junk[i % 4]) for i, d in enumerate(stored))
    # The drops past the budget are counted, at the end of the record.
    (event,) = [e for e in run.events if e.key == "drops_not_stored"]
    assert event.payload["n"] == 10_000 - len(stored)
    assert event.payload["n_bytes"] == 50_000 * (10_000 - len(stored))


def test_a_version_1_record_with_drops_in_full_still_reads(tmp_path):
    pack = msgpack.Packer(use_bin_type=True).pack
    frames = [
        {"format": "neuvision-record", "v": 1, "t0_wall_ns": 0, "host": {}},
        [1, "rx", "nv/s/body/0/sensors", _reading(0).encode()],
        [2, "drop", "nv/s/body/0/sensors", _reading(5).encode()],
    ]
    (tmp_path / RECORD_FILE).write_bytes(b"".join(map(pack, frames)))
    run = read_run(tmp_path)
    assert [r.step for r in run.decoded(SensorReading, "rx")] == [0]
    assert run.drops[0].payload == _reading(5).encode()


def test_with_the_default_budget_10000_drops_are_all_stored_in_under_2_mb(tmp_path):
    junk = np.random.default_rng(1).bytes(50_000)
    rec = Recorder(tmp_path)
    for _ in range(10_000):
        rec.message("drop", "nv/s/culture/0/spikes", junk)
    rec.close()
    assert (tmp_path / RECORD_FILE).stat().st_size < 2 << 20
    run = read_run(tmp_path)
    assert len(run.drops) == 10_000 and not [e for e in run.events if e.key == "drops_not_stored"]


def _manifest_of(tmp_path, **hub) -> None:
    manifest = {"outcome": "running", "hosts": {"hub": {"hostname": socket.gethostname(), **hub}}}
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))


def test_a_run_whose_hub_is_gone_reads_as_unfinished_not_running(tmp_path):
    """A hub killed outright (or its host restarted) leaves its manifest saying "running"
    for ever, and the analysis reported the run as running. Read back, a run whose hub's
    process no longer exists is "unfinished", saying why; the file is left as it was."""
    ended = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                           capture_output=True, text=True, check=True)  # fmt: skip
    _manifest_of(tmp_path, pid=int(ended.stdout))
    manifest = read_run(tmp_path).manifest
    assert manifest["outcome"] == "unfinished"
    assert "its hub ended without closing the run" in manifest["reason"]
    assert json.loads((tmp_path / "manifest.json").read_text())["outcome"] == "running"


def test_a_run_whose_hub_lives_reads_as_running(tmp_path):
    me = host()  # this process: as a hub still stepping
    _manifest_of(tmp_path, pid=me["pid"], pid_start_ticks=me.get("pid_start_ticks"))
    assert read_run(tmp_path).manifest["outcome"] == "running"


def test_a_reused_pid_is_not_taken_for_the_runs_hub(tmp_path):
    me = host()
    if "pid_start_ticks" not in me:
        pytest.skip("no /proc: a process's start time is unknown here")
    _manifest_of(tmp_path, pid=me["pid"], pid_start_ticks=me["pid_start_ticks"] - 1)
    assert read_run(tmp_path).manifest["outcome"] == "unfinished"


def test_a_run_written_on_another_host_is_not_judged(tmp_path):
    _manifest_of(tmp_path, pid=1, pid_start_ticks=0)
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    manifest["hosts"]["hub"]["hostname"] = "another-host.invalid"
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    assert read_run(tmp_path).manifest["outcome"] == "running"


def _steps(run_dir, inputs: int, replies: int, manifest_steps: int):
    run_dir.mkdir()
    write_manifest(run_dir, {"steps": manifest_steps, "outcome": "completed"})
    rec = Recorder(run_dir)
    for _ in range(inputs):
        rec.message("tx", "nv/s/body/0/motor", b"m")
    for k in range(replies):
        rec.message("rx", "nv/s/body/0/sensors", _reading(k).encode())
    rec.close()
    return read_run(run_dir)


def test_a_record_says_how_many_of_its_runs_steps_it_holds(tmp_path):
    # an input a step, and the robot's stop after the last
    whole = _steps(tmp_path / "whole", inputs=11, replies=10, manifest_steps=10)
    assert whole.steps_recorded() == 10 and whole.short_note() == ""
    cut = _steps(tmp_path / "cut", inputs=7, replies=6, manifest_steps=10)  # hub killed, say
    assert cut.steps_recorded() == 7
    assert cut.short_note().startswith("the record holds 7 of the run's 10 steps")
    (tmp_path / "cut" / RECORD_FILE).unlink()  # removed: not "cut short or damaged"
    gone = read_run(tmp_path / "cut")
    assert gone.short_note().startswith("the run folder holds no record.nvrec")
