"""A run exported to NWB reads back with pynwb holding exactly what the record holds."""

from __future__ import annotations

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
