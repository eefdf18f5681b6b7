"""The scripts in examples/ run (shortened), from another folder than the repository."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
pytestmark = pytest.mark.bus


def load(name: str):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # a scheme defined in it is imported by its module's name
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_the_papers_closed_loop_against_its_control(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    results = load("paper_closed_loop").main(seeds=1, duration_s=1.0, runs_dir=tmp_path)
    assert set(results) == {"closed_loop", "closed_loop_blind"}
    assert all(len(runs) == 1 and runs[0]["distance_m"] > 0 for runs in results.values())


@pytest.mark.slow  # a whole run
def test_a_coding_scheme_written_in_the_script(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    run = load("custom_coding").main(duration_s=2.0, runs_dir=tmp_path)
    assert run.outcome == "completed" and run.steps == 200
    assert run.manifest["config"]["coding"]["scheme"] == "custom_coding:nearest_sensor"
    pulses = run.stimulation
    assert np.all(np.diff(pulses["t_ms"]) >= 0)
    assert np.all(pulses["amplitude_ua"] <= 100.0)


@pytest.mark.slow  # several runs of a script: tens of seconds
def test_a_parameter_sweep(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rows = load("parameter_sweep").main(duration_s=1.0, runs_dir=tmp_path)
    assert [r["gain"] for r in rows] == [1.0, 2.0, 4.0, 6.0]
    assert len(list(tmp_path.glob("*/manifest.json"))) == 4
