"""The paper's closed loop end to end: `neuvision run` on the shipped experiment files."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from hub.analysis.bursts import detect_bursts
from hub.analysis.network_bursts import NetworkBurstParams, detect_network_bursts
from hub.protocol import MotorCommand, SensorReading, SpikeBatch, Stimulation
from hub.record import read_run
from tests.conftest import TEST_ENDPOINTS
from tests.stall_witness import StallWitness

pytestmark = pytest.mark.bus


def neuvision(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "hub.cli", *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=cwd,
    )


def _run(tmp_path, config, bus_overrides, *extra):
    sets = [a for o in bus_overrides if not o.startswith("bus.listen") for a in ("--set", o)]
    proc = neuvision(
        "run", config, "--duration-s", "3", "--runs-dir", str(tmp_path), "--quiet", *sets, *extra
    )
    assert proc.returncode == 0, proc.stderr
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    return run_dir, proc


def test_the_closed_loop_run_leaves_a_record_a_summary_and_pictures(tmp_path, bus_overrides):
    run_dir, proc = _run(tmp_path, "configs/closed_loop.toml", bus_overrides)
    assert "completed after 300 steps" in proc.stderr
    for name in ("manifest.json", "record.nvrec", "summary.json", "trajectory.png", "raster.png"):
        assert (run_dir / name).stat().st_size > 0, name
    summary = json.loads((run_dir / "summary.json").read_text())
    behaviour = summary["behaviour"]
    for key in (
        "distance_m",
        "obstacle_entries",
        "arena_exits",
        "time_in_obstacles_s",
        "coverage_fraction",
        "mean_speed_mps",
    ):
        assert key in behaviour
    assert summary["timing"]["steps"] == 300 and summary["timing"]["x_realtime"] > 0
    rec = read_run(run_dir)
    assert rec.manifest["outcome"] == "completed"
    assert len(rec.decoded(SpikeBatch, "rx")) == 300
    assert len(rec.decoded(SensorReading, "rx")) == 300
    # With feedback, the sensors are coded into pulses on the culture.
    assert sum(s.n_pulses for s in rec.decoded(Stimulation, "tx")) > 0
    t_s, poses = rec.trajectory()
    assert behaviour["distance_m"] == pytest.approx(
        np.hypot(*np.diff(poses[:, :2], axis=0).T).sum(), rel=1e-6
    )
    # The hub's live detection, fed while it waits for replies, finds what offline
    # detection finds in the record.
    bursts = detect_bursts(*rec.spikes())
    n_channels = rec.descriptions()["culture"].channel.size
    network = detect_network_bursts(bursts, n_channels, NetworkBurstParams())
    assert rec.manifest["counts"]["single_channel_bursts_online"] == len(bursts) > 0
    assert rec.manifest["counts"]["network_bursts_online"] == len(network)
    assert len([e for e in rec.events if e.key == "network_burst"]) == len(network)


@pytest.mark.slow  # a whole run
def test_a_blind_run_sends_no_stimulation(tmp_path, bus_overrides):
    run_dir, _ = _run(tmp_path, "configs/closed_loop_blind.toml", bus_overrides)
    rec = read_run(run_dir)
    stims = rec.decoded(Stimulation, "tx")
    assert len(stims) == 300 and all(s.n_pulses == 0 for s in stims)
    # The culture still drives the robot on its spontaneous activity.
    assert any(m.left_mps != 0 or m.right_mps != 0 for m in rec.decoded(MotorCommand, "tx"))


def _contents(messages) -> list[dict]:
    """What messages say, but for the run they belong to (each run has its own id)."""
    return [{k: v for k, v in m.to_dict().items() if k != "run"} for m in messages]


@pytest.mark.slow
def test_lockstep_runs_with_the_same_seed_are_identical(tmp_path, bus_overrides):
    a, _ = _run(tmp_path / "a", "configs/closed_loop.toml", bus_overrides, "--seed", "5")
    b, _ = _run(tmp_path / "b", "configs/closed_loop.toml", bus_overrides, "--seed", "5")
    ra, rb = read_run(a), read_run(b)
    for kind in (SpikeBatch, SensorReading):
        assert _contents(ra.decoded(kind, "rx")) == _contents(rb.decoded(kind, "rx"))


@pytest.mark.parametrize(
    "override, message",
    [
        ("loop.period_ms=-5", "loop.period_ms must be >= 0.1, got -5"),
        ('body.params.world="no/such/world.toml"', "body.params.world: world file"),
        ("culture.cpus=[100000]", "culture.cpus: CPU 100000 is not available to this process"),
    ],
)
def test_a_bad_config_names_the_key_and_starts_nothing(tmp_path, override, message):
    proc = neuvision(
        "run", "configs/closed_loop.toml", "--set", override, "--runs-dir", str(tmp_path)
    )
    assert proc.returncode == 3
    assert message in proc.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow  # a whole run
def test_record_info_summarises_a_run(tmp_path, bus_overrides):
    run_dir, _ = _run(tmp_path, "configs/closed_loop_blind.toml", bus_overrides)
    proc = neuvision("record-info", str(run_dir))
    info = json.loads(proc.stdout)
    assert info["outcome"] == "completed" and info["steps"] == 300
    assert any(k.endswith("/spikes") for k in info["messages"])


@pytest.mark.slow  # a whole run's start-up
def test_an_endpoint_that_cannot_start_ends_the_run_at_once_with_its_reason(tmp_path):
    proc = neuvision(
        "run",
        "configs/closed_loop.toml",
        "--set",
        # a kind without check_config: its parameters are checked only when it starts
        'body.kind="tests.endpoints:EchoBody"',
        "--set",
        "body.params.nope=1",
        "--runs-dir",
        str(tmp_path),
        "--quiet",
    )
    assert proc.returncode == 2
    assert "body endpoint exited with status 3" in proc.stderr
    assert "body.params.nope is not a parameter" in proc.stderr


@pytest.mark.slow  # a whole run's start-up
def test_an_endpoint_that_fails_mid_run_is_named_with_its_own_last_word(tmp_path):
    """The hub sees a failed endpoint only vanish ("died at step N"); the cause is the
    endpoint's, and `neuvision run` now says it too, not only the endpoint's log."""
    sets = [*TEST_ENDPOINTS, 'body.kind="tests.endpoints:FailingDeviceBody"',
            "body.params={fail_at=20}"]  # fmt: skip
    proc = neuvision(
        "run", *[a for s in sets for a in ("--set", s)],
        "--duration-s", "2", "--runs-dir", str(tmp_path), "--quiet",
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr[-2000:]
    # the step under way when the hub saw it vanish: the body runs up to a step ahead of
    # the culture in lockstep's pipeline, so step 19 or 20
    assert re.search(r"body/0 died at step (19|20) ", proc.stderr), proc.stderr
    assert "body endpoint exited with status 2: " in proc.stderr
    assert "the test device's line failed at step 20" in proc.stderr
    # and the run's record says it beside the hub's reason
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert re.search(r"body/0 died at step (19|20) ", manifest["reason"])
    # what it recorded is summarised, as for any run
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["outcome"] == "fault" and summary["steps"] in (19, 20)
    (exit_,) = manifest["local_endpoint_exits"].values()
    assert exit_["status"] == 2 and "the test device's line failed at step 20" in exit_["last_line"]


@pytest.mark.slow  # a run, then its analysis and figures
def test_analyze_writes_metrics_figures_and_a_report_for_a_closed_loop_run(tmp_path, bus_overrides):
    run_dir, _ = _run(tmp_path, "configs/closed_loop.toml", bus_overrides)
    proc = neuvision("analyze", str(run_dir), "--out", str(tmp_path / "an"))
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads((tmp_path / "an" / "metrics.json").read_text())
    assert metrics["mfr_hz"] > 0
    assert (tmp_path / "an" / "report.html").stat().st_size > 10_000
    assert (tmp_path / "an" / "trajectory.png").exists()


@pytest.mark.slow
def test_pipelined_lockstep_gives_what_a_strict_step_by_step_loop_gives(tmp_path, bus_overrides):
    # Realtime mode runs strictly one step after another; with a deadline long enough
    # that no reply is missed, its endpoints see exactly the inputs of the Jacobi scheme.
    # The body must still answer within its period (10 ms): a reply the host held past
    # that (the stall witness saw it) leaves the policy's stand-in and nothing to compare,
    # and that run alone is tried again; a miss the host does not explain fails.
    a, _ = _run(tmp_path / "a", "configs/closed_loop.toml", bus_overrides, "--seed", "2")
    for attempt in range(2):
        with StallWitness() as witness:
            b, _ = _run(
                tmp_path / f"b{attempt}",
                "configs/closed_loop.toml",
                bus_overrides,
                "--seed",
                "2",
                "--mode",
                "realtime",
                "--set",
                "loop.deadline_ms=2000",
            )
        rb = read_run(b)
        missed = [e for e in rb.events if e.key == "missed"]
        if not missed:
            break
        assert witness.explains_every_miss(rb), (missed, witness.summary())
    ra = read_run(a)
    assert not missed, f"a realtime reply was late twice where the host stalled: {missed}"
    for kind in (SpikeBatch, SensorReading):
        assert _contents(ra.decoded(kind, "rx")) == _contents(rb.decoded(kind, "rx"))


@pytest.mark.slow  # two runs
def test_a_recorded_run_runs_again_from_its_folder_with_the_same_spikes(tmp_path, bus_overrides):
    """The manifest holds the resolved config (the culture's and the world's contents):
    the run folder alone is enough to run it again, even with its files gone."""
    first, _ = _run(tmp_path / "a", "configs/closed_loop.toml", bus_overrides)
    sets = [a for s in bus_overrides for a in ("--set", s)]
    again = neuvision("run", str(first), *sets, "--runs-dir", str(tmp_path / "b"), "--quiet")
    assert again.returncode == 0, again.stderr[-2000:]
    (second,) = (tmp_path / "b").iterdir()
    a, b = read_run(first), read_run(second)
    for x, y in zip(a.spikes(), b.spikes(), strict=True):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a.trajectory()[1], b.trajectory()[1])
    assert b.manifest["config_source"] == str(first)
