"""The Python API: experiments changed by key and checked at once; runs read as arrays."""

from __future__ import annotations

import numpy as np
import pytest

from hub.protocol import MotorCommand, SensorReading, SpikeBatch, Stimulation
from hub.record import RunReadError
from neuvision import ConfigError, Experiment, Run

CONFIG = "configs/closed_loop.toml"


def test_a_bad_change_is_named_and_leaves_the_experiment_as_it_was():
    exp = Experiment(CONFIG, {"experiment.duration_s": 1.0})
    with pytest.raises(ConfigError, match="loop.period_ms must be >= 0.1"):
        exp.set("loop.period_ms", 0.0)
    assert exp.overrides == {"experiment.duration_s": 1.0}
    assert exp.set("loop.period_ms", 20.0).cfg.loop.period_ms == 20.0


@pytest.mark.parametrize(
    "key, value, named",
    [
        ("culture.params.noise.sd", -1, "culture.params.noise.sd must be >= 0"),
        ("culture.params.config", "/nope.toml", "culture.params.config: culture file"),
        ("body.params.world", "/nope.toml", "body.params.world: world file"),
        ("coding.scheme", "nomod:x", "coding.scheme: cannot import 'nomod'"),
        ("coding.params.sites_per_sensor", -5, "coding.params.sites_per_sensor must be >= 1"),
        # a change that breaks a key it leaves alone (the pulses' period follows the loop's)
        ("loop.period_ms", 5.0, r"pulse_period_ms \(its default: loop.period_ms\) must be"),
    ],
)
def test_a_change_is_checked_as_neuvision_run_checks_it(key, value, named):
    """`set` checked only the keys' types and bounds: a culture file that is not there, a
    scheme's parameter, were found only at `run`."""
    exp = Experiment(CONFIG)
    with pytest.raises(ConfigError, match=named):
        exp.set(key, value)
    assert exp.overrides == {}


def test_a_bad_file_or_key_fails_when_the_experiment_is_made(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        Experiment(tmp_path / "nowhere.toml")
    with pytest.raises(ConfigError, match="loop.mode"):
        Experiment(CONFIG, {"loop.mode": "sometimes"})
    with pytest.raises(ConfigError, match="config must be an experiment file's path"):
        Experiment(123)  # was a TypeError from deep in pathlib


def test_a_folder_that_is_not_a_run_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="not a run folder"):
        Run.open(tmp_path)


def test_a_runs_manifest_is_read_without_its_record(tmp_path):
    (tmp_path / "manifest.json").write_text('{"outcome": "completed", "steps": 3}')
    (tmp_path / "record.nvrec").write_bytes(b"not a record")  # a reader would refuse it
    run = Run.open(tmp_path)
    assert (run.outcome, run.steps) == ("completed", 3)
    assert repr(run) == f"Run({str(tmp_path)!r}, outcome='completed', steps=3)"
    with pytest.raises(RunReadError):  # the record is read when asked for, not before
        _ = run.record


@pytest.mark.slow  # a whole run
@pytest.mark.bus
def test_a_run_gives_the_records_data_as_arrays_in_time_order(tmp_path):
    run = Experiment(CONFIG, {"experiment.duration_s": 1.0}).run(runs_dir=tmp_path)
    rec = run.record
    assert run.outcome == "completed" and run.steps == 100
    channel, t_ms = run.spikes
    assert channel.size == sum(b.channel.size for b in rec.decoded(SpikeBatch, "rx"))
    assert np.all(np.diff(t_ms) >= 0)
    t_s, poses = run.trajectory
    assert poses.shape == (100, 3) and np.all(np.diff(t_s) > 0)
    t_s, ranges = run.sensors
    assert ranges.shape == (100, rec.descriptions()["body"].n_sensors)
    assert len(rec.decoded(SensorReading, "rx")) == 100
    t_s, wheels = run.motor
    assert wheels.shape == (len(rec.decoded(MotorCommand, "tx")), 2)  # the final stop too
    assert np.all(wheels[-1] == 0)
    pulses = run.stimulation
    assert pulses["t_ms"].size == sum(s.n_pulses for s in rec.decoded(Stimulation, "tx"))
    assert run.summary["outcome"] == "completed"


@pytest.mark.slow  # a whole run
@pytest.mark.bus
def test_an_experiment_copied_elsewhere_runs_from_any_folder(tmp_path, monkeypatch):
    import shutil

    mine = tmp_path / "myexp"
    shutil.copytree("configs", mine)
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    run = Experiment("../myexp/closed_loop.toml", {"experiment.duration_s": 0.5}).run()
    assert run.outcome == "completed" and run.steps == 50
    assert run.run_dir.resolve().parent == tmp_path / "elsewhere" / "runs"  # from here
    assert run.manifest["config"]["culture"]["params"]["config"]["layout"]["rows"] == 32
