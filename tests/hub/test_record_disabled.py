"""``record.enabled = false``: the run records no messages, only its manifest (what ran, its
outcome, timing and counts) beside the endpoints' logs, and says so; the commands that need
the record say in one line that there is none."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from hub.cli import EXIT_CONFIG, EXIT_OK
from tests.conftest import TEST_ENDPOINTS


def neuvision(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "hub.cli", *args], capture_output=True, text=True, timeout=120
    )


@pytest.mark.slow  # a whole run
def test_a_run_without_its_record_keeps_its_manifest_and_says_nothing_was_recorded(
    tmp_path, bus_overrides
):
    sets = [*TEST_ENDPOINTS, *bus_overrides, "record.enabled=false"]
    done = neuvision(
        "run", "--quiet", "--runs-dir", str(tmp_path), "--duration-s", "0.2",
        *(a for s in sets for a in ("--set", s)),
    )  # fmt: skip
    assert done.returncode == EXIT_OK, done.stderr
    (run_dir,) = tmp_path.iterdir()
    last = done.stderr.strip().splitlines()[-1]
    assert "completed after 20 steps" in last
    assert f"nothing recorded (record.enabled = false): manifest and logs in {run_dir}" in last
    assert sorted(p.name for p in run_dir.iterdir()) == ["body.log", "culture.log", "manifest.json"]
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert (manifest["outcome"], manifest["steps"]) == ("completed", 20)
    assert manifest["config"]["record"]["enabled"] is False

    info = neuvision("record-info", str(run_dir))  # what there is: the manifest's outcome
    assert info.returncode == EXIT_OK and json.loads(info.stdout)["frames"] == 0
    for command in (["analyze", str(run_dir)], ["export", str(run_dir), "--nwb", "x.nwb"]):
        refused = neuvision(*command)
        assert refused.returncode == EXIT_CONFIG, refused.stderr
        assert refused.stderr.count("\n") == 1
        assert "holds no record.nvrec (a run made with record.enabled = false" in refused.stderr
