"""``neuvision compare`` in parallel: no run lost, and a failed run named with its reason."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.bus, pytest.mark.slow]


def test_parallel_runs_of_eight_seeds_lose_nothing_and_name_an_injected_failure(tmp_path):
    # A third condition that fails only once its run starts (a bad file stops the whole
    # comparison before any run): more stimulation sites than the culture has channels,
    # which the coder finds when the endpoints have described themselves.
    broken = tmp_path / "broken.toml"
    base = Path("configs/closed_loop.toml").resolve()
    broken.write_text(
        f'extends = "{base}"\n[experiment]\nname = "broken"\n'
        "[coding]\nparams = { sites_per_sensor = 200 }\n"
    )
    out = tmp_path / "cmp"
    cmd = [sys.executable, "-m", "hub.cli", "compare", "configs/closed_loop.toml",
           "configs/closed_loop_blind.toml", str(broken), "--seeds", "8", "--jobs", "4",
           "--duration-s", "1", "--out", str(out)]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert done.returncode == 2, done.stderr[-3000:]  # some runs failed: said by the status
    result = json.loads((out / "compare.json").read_text())
    runs = result["runs"]
    assert len(runs) == 24
    failed = [r for r in runs if not r["ok"]]
    assert {r["condition"] for r in failed} == {"broken"} and len(failed) == 8
    assert all("exit status 2" in r["reason"] and "sites_per_sensor" in r["reason"] for r in failed)
    for name in ("closed_loop", "closed_loop_blind"):
        assert result["stats"][name]["distance_m"]["n"] == 8  # none of them lost
    table = (out / "compare.md").read_text()
    assert table.startswith("# closed_loop vs closed_loop_blind vs broken: seeds 1-8, runs of")
    assert "**Failed runs: 8**" in table and "| broken | 8 | exit status 2" in table
    # which settings each condition had: its file, and what every run was given
    assert f"- **broken**: `{broken}`" in table and "- **closed_loop**: `configs/" in table
    assert "Given to every run: `--set experiment.duration_s=1.0`." in table
    assert result["condition_files"]["broken"] == str(broken)
    assert any(t["b"] == "closed_loop_blind" and t["n_a"] == t["n_b"] == 8
               for t in result["tests"])  # fmt: skip
