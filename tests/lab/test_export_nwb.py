"""A run exported to NWB reads back with pynwb holding exactly what the record holds."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from neuvision import Experiment

ROOT = Path(__file__).resolve().parents[2]

pynwb = pytest.importorskip("pynwb")


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("nwb")
    run = Experiment("configs/closed_loop.toml", {"experiment.duration_s": 1.0}).run(tmp / "runs")
    path = tmp / "run.nwb"
    done = subprocess.run(
        [sys.executable, "-m", "hub.cli", "export", str(run.run_dir), "--nwb", str(path)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return run, path


def test_spikes_pulses_poses_and_commands_round_trip(exported):
    run, path = exported
    with pynwb.NWBHDF5IO(str(path), "r") as io:
        f = io.read()
        channel, t_ms = run.spikes
        units = f.units.to_dataframe()
        assert sum(len(t) for t in units["spike_times"]) == channel.size
        for c, times in zip(units["channel"], units["spike_times"], strict=True):
            np.testing.assert_allclose(times, np.sort(t_ms[channel == c]) / 1e3)
        culture = run.record.descriptions()["culture"]
        assert len(f.electrodes) == culture.channel.size
        np.testing.assert_allclose(f.electrodes["rel_x"][:], culture.x_um)
        pulses = f.intervals["stimulation"].to_dataframe()
        assert len(pulses) == run.stimulation["t_ms"].size
        np.testing.assert_allclose(pulses["amplitude_ua"], run.stimulation["amplitude_ua"])
        behaviour = f.processing["behavior"]
        t_s, poses = run.trajectory
        xy = behaviour["Position"]["pose_xy"]
        np.testing.assert_allclose(xy.data[:], poses[:, :2])
        np.testing.assert_allclose(xy.timestamps[:], t_s)
        assert behaviour["motor_commands"].data.shape == run.motor[1].shape
        assert behaviour["sensor_ranges"].data.shape == run.sensors[1].shape
        assert f.identifier == run.manifest["run_id"]
        assert "[experiment]" in f.protocol  # the experiment file itself
        assert '"sites_per_sensor": 4' in f.protocol  # ... and the config resolved
        # run time 0 on the file's clock is step 0's first input leaving the hub, not the
        # run folder's making (the wait for the endpoints lay between them)
        first_tx = next(fr for fr in run.record.frames if fr.direction == "tx")
        zero_s = f.timestamps_reference_time.timestamp()
        assert zero_s == pytest.approx(first_tx.t_wall_ns / 1e9, abs=1e-3)
        assert zero_s > f.session_start_time.timestamp()
        assert "izhikevich neurons" in f.subject.description
        assert "µm" in f.electrode_groups["culture"].description


@pytest.mark.slow  # a run and its export
def test_the_protocol_is_the_file_that_ran_not_the_file_as_it_is_now(tmp_path):
    configs = ROOT / "configs"
    experiment = tmp_path / "exp.toml"
    experiment.write_text(
        '# THE FILE THAT RAN\n[experiment]\nname = "exp"\nduration_s = 0.2\n'
        f'[body]\nparams = {{ world = "{configs / "worlds" / "paper.toml"}" }}\n'
        f'[culture]\nparams = {{ config = "{configs / "culture_1024.toml"}" }}\n'
    )
    run = Experiment(experiment).run(tmp_path / "runs")
    experiment.write_text("# EDITED AFTER THE RUN\n")
    path = tmp_path / "run.nwb"
    done = subprocess.run(
        [sys.executable, "-m", "hub.cli", "export", str(run.run_dir), "--nwb", str(path)],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    with pynwb.NWBHDF5IO(str(path), "r") as io:
        protocol = io.read().protocol
    assert "# THE FILE THAT RAN" in protocol and "EDITED" not in protocol
    assert '"duration_s": 0.2' in protocol


def test_nwbs_own_inspector_finds_nothing_critical(exported):
    nwbinspector = pytest.importorskip("nwbinspector")
    _, path = exported
    messages = list(nwbinspector.inspect_nwbfile(nwbfile_path=str(path)))
    critical = [m for m in messages if m.importance.name in ("CRITICAL", "PYNWB_VALIDATION")]
    assert critical == [], [m.message for m in critical]


def test_a_folder_that_is_not_a_run_is_one_line(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "hub.cli", "export", str(tmp_path), "--nwb", "x.nwb"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert done.returncode == 3 and done.stderr.count("\n") == 1


def _run_without_steps(run_dir, steps: int = 0):
    """A run folder as the hub leaves it when the run ends at ``steps`` steps with no spike:
    the culture described itself, then a fault (steps 0: before the first step)."""
    from hub.protocol import Description, Keys
    from hub.record import Recorder, utc_now, write_manifest

    run_dir.mkdir()
    recorder = Recorder(run_dir)
    culture = Description(
        role="culture",
        id="0",
        kind="sim_network",
        channel=np.arange(4, dtype="<u4"),
        x_um=np.arange(4, dtype="<f4"),
        y_um=np.zeros(4, dtype="<f4"),
        cell_type=np.zeros(4, dtype="u1"),
    )
    recorder.message("rx", Keys("default").describe("culture", "0"), culture.encode())
    recorder.event("fault", reason="body/0 refused the run: no serial port")
    recorder.close()
    manifest = {"name": "t", "seed": 1, "run_id": "r1", "start_utc": utc_now(), "config": {}}
    reason = "body/0 refused the run: no serial port"
    write_manifest(run_dir, {**manifest, "outcome": "fault", "reason": reason, "steps": steps})
    return run_dir


def _export(run_dir, path):
    return subprocess.run(
        [sys.executable, "-m", "hub.cli", "export", str(run_dir), "--nwb", str(path)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip


def test_a_run_that_ended_before_its_first_step_is_refused_in_one_line_and_no_file_is_left(
    tmp_path,
):
    run_dir = _run_without_steps(tmp_path / "run")
    done = _export(run_dir, tmp_path / "fault.nwb")
    assert done.returncode == 3, done.stderr
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr
    assert "holds no data to export" in done.stderr
    assert "fault: body/0 refused the run: no serial port" in done.stderr  # why
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no file, whole or partial


def test_a_run_in_which_no_channel_fired_has_an_empty_but_typed_units_table(tmp_path):
    run_dir = _run_without_steps(tmp_path / "run", steps=3)
    path = tmp_path / "silent.nwb"
    done = _export(run_dir, path)
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "silent.nwb"]
    with pynwb.NWBHDF5IO(str(path), "r") as io:
        f = io.read()
        assert len(f.units) == 0 and f.units["channel"].data.dtype.kind == "i"
        np.testing.assert_allclose(f.electrodes["rel_x"][:], np.arange(4))


def test_a_path_that_is_not_a_file_is_refused_and_left_as_it_is(tmp_path):
    run_dir = _run_without_steps(tmp_path / "run", steps=3)
    fifo = tmp_path / "pipe.nwb"  # what /dev/full or a named pipe would be
    os.mkfifo(fifo)
    done = _export(run_dir, fifo)
    assert done.returncode == 3 and done.stderr.count("\n") == 1, done.stderr
    assert "is not a file" in done.stderr
    assert stat.S_ISFIFO(fifo.stat().st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe.nwb", "run"]


def test_a_file_the_file_system_refuses_is_one_line_and_leaves_nothing(tmp_path):
    run_dir = _run_without_steps(tmp_path / "run", steps=3)
    too_long = tmp_path / ("n" * 250 + ".nwb")  # the file system's limit is 255 bytes
    done = _export(run_dir, too_long)
    assert done.returncode == 3 and done.stderr.count("\n") == 1, done.stderr
    assert "cannot write" in done.stderr and "Traceback" not in done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_a_full_disk_is_one_error_and_leaves_no_file(tmp_path, monkeypatch):
    """HDF5 writing into a full disk crashed the interpreter at its exit, after the error;
    the file is now built in memory and written whole."""
    import errno

    from lab.export_nwb import ExportError, export_nwb

    run_dir = _run_without_steps(tmp_path / "run", steps=3)
    write_bytes = Path.write_bytes

    def full_disk(path, data):
        write_bytes(path, bytes(data)[:10])  # some of it, then no room
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_bytes", full_disk)
    with pytest.raises(ExportError, match="cannot write .*run.nwb: No space left on device"):
        export_nwb(run_dir, tmp_path / "run.nwb")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
