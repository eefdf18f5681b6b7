"""A run exported to NWB reads back with pynwb holding exactly what the record holds."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from neuvision import Experiment

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
