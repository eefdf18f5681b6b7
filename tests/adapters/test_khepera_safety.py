"""Whatever ends a run, the Khepera's motors stop: the hub killed, the adapter terminated,
the robot's link gone. Real processes, real Zenoh on loopback, a real pseudo-terminal."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from adapters.khepera.emulator import KheperaEmulator
from hub.record import read_run
from tests.adapters.khepera_rig import motor_commands
from tests.harness import wait_for

pytestmark = pytest.mark.bus
HYBRID = "configs/hybrid_khepera.toml"
WATCHDOG_S = 0.5


def neuvision(*args, **popen) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "hub.cli", *args], **popen)


def sets(bus_overrides, port, *more) -> list[str]:
    out = []
    for item in [*bus_overrides, f'body.params.port="{port}"', *more]:
        out += ["--set", item]
    return out


def moving(emulator) -> bool:
    return emulator.speed_units != (0, 0)


def end(*procs: subprocess.Popen) -> None:
    for p in procs:
        if p.poll() is None:
            p.kill()
        p.wait(timeout=10)


def children(pid: int) -> list[int]:
    """The child processes of ``pid`` (Linux ``/proc``)."""
    out = []
    for task in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{task}/children") as f:
            out += [int(c) for c in f.read().split()]
    return out


def gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] == "Z"  # a zombie has ended
    except FileNotFoundError:
        return True


@pytest.fixture
def emulator():
    with KheperaEmulator(baud=115200) as emu:
        yield emu


def started(emulator, bus_overrides, tmp_path, body_stderr=subprocess.DEVNULL, **hub_kwargs):
    """The Khepera adapter served on its own (as on a lab PC) and a 60 s hybrid run by a hub."""
    args = sets(bus_overrides, emulator.path, 'body.launch="external"')
    text = body_stderr is subprocess.PIPE
    body = neuvision("endpoint", "body", HYBRID, *args, stderr=body_stderr, text=text)
    hub = neuvision(
        "run", HYBRID, "--quiet", "--duration-s", "60", "--runs-dir", str(tmp_path), *args,
        stderr=subprocess.DEVNULL, **hub_kwargs,
    )  # fmt: skip
    return body, hub


def test_the_hub_killed_mid_run_leaves_the_robot_stopped_within_the_watchdog(
    emulator, bus_overrides, tmp_path
):
    body, hub = started(emulator, bus_overrides, tmp_path, start_new_session=True)
    try:
        wait_for(lambda: moving(emulator), 60.0)
        os.killpg(hub.pid, signal.SIGKILL)  # the hub and its culture, at once
        killed = time.monotonic()
        wait_for(lambda: not moving(emulator), 5.0)
        t_stop, line = motor_commands(emulator)[-1]
        assert line == b"D,0,0"
        assert t_stop - killed <= WATCHDOG_S + 0.2  # the watchdog, or the hub's liveliness
        assert body.poll() is None  # the adapter lives on, idle, for the next run
    finally:
        end(hub, body)


def test_the_adapter_killed_outright_leaves_the_robot_stopped(emulator, bus_overrides, tmp_path):
    """SIGKILL to the adapter (or the OOM killer, or a crash in C): no code of its own runs,
    and a Khepera's protocol has no watchdog of its own — the robot drove on at its last
    speed. The adapter's stop guard, a process that holds the port with it, sends the stop
    when the adapter's process ends without releasing it, and then ends itself."""
    body, hub = started(emulator, bus_overrides, tmp_path, body_stderr=subprocess.PIPE)
    try:
        wait_for(lambda: moving(emulator), 60.0)
        guards = children(body.pid)
        assert len(guards) == 1  # the stop guard
        body.kill()
        killed = time.monotonic()
        wait_for(lambda: not moving(emulator), 5.0)
        t_stop, line = motor_commands(emulator)[-1]
        assert line == b"D,0,0"
        assert t_stop - killed <= 0.5
        wait_for(lambda: gone(guards[0]), 5.0)  # it ends once the stop is sent
        assert "stop guard" in body.stderr.read()  # it says what it did
    finally:
        end(hub, body)


def test_a_stop_guard_killed_is_replaced_so_the_adapters_death_still_stops_the_robot(
    emulator, bus_overrides, tmp_path
):
    """The guard killed on its own (by hand, the OOM killer) left the device unguarded
    and nobody knew: the adapter's death then left the robot driving on. The adapter sees
    it at its next beat and starts another."""
    body, hub = started(emulator, bus_overrides, tmp_path, body_stderr=subprocess.PIPE)
    try:
        wait_for(lambda: moving(emulator), 60.0)
        (first,) = children(body.pid)
        os.kill(first, signal.SIGKILL)
        wait_for(lambda: [g for g in children(body.pid) if not gone(g)] not in ([], [first]), 5.0)
        (second,) = [g for g in children(body.pid) if not gone(g)]
        wait_for(lambda: moving(emulator), 5.0)  # the run goes on
        body.kill()
        wait_for(lambda: not moving(emulator), 5.0)
        assert motor_commands(emulator)[-1][1] == b"D,0,0"
        wait_for(lambda: gone(second), 5.0)
        err = body.stderr.read()
        assert f"stop guard of the khepera on {emulator.path} (pid {first}) ended" in err
        assert "a new one stands" in err
    finally:
        end(hub, body)


def test_the_adapter_frozen_mid_run_leaves_the_robot_stopped(emulator, bus_overrides, tmp_path):
    """SIGSTOP to the adapter (a debugger, a swap storm, a hung thread): none of its own
    code runs, and it does not end either, so nothing stopped the robot — it drove on at
    its last speed for as long as the adapter stood. Its serial thread beats the stop
    guard each cycle; the guard sends the stop once the beats are missing for
    ``body.params.freeze_s`` (1 s), and watches on when the adapter is back."""
    body, hub = started(emulator, bus_overrides, tmp_path, body_stderr=subprocess.PIPE)
    try:
        wait_for(lambda: moving(emulator), 60.0)
        body.send_signal(signal.SIGSTOP)
        frozen = time.monotonic()
        wait_for(lambda: not moving(emulator), 5.0)
        t_stop, line = motor_commands(emulator)[-1]
        assert line == b"D,0,0"
        assert 1.0 - 0.1 <= t_stop - frozen <= 1.0 + 0.5  # freeze_s, and a cycle's beat
        body.send_signal(signal.SIGCONT)
        assert hub.wait(timeout=30) == 2  # the body stood past its lease: the run's fault
        time.sleep(0.5)
        assert not moving(emulator)  # back, it drives not on at its old speed
        body.send_signal(signal.SIGTERM)
        assert body.wait(timeout=10) == 0
        err = body.stderr.read()
        assert "gave no sign of life for 1 s" in err and "alive again" in err
        assert "stopped the motors while this process was frozen" in err
    finally:
        end(hub, body)


def test_sigterm_to_the_adapter_stops_the_motors_before_it_exits(emulator, bus_overrides, tmp_path):
    body, hub = started(emulator, bus_overrides, tmp_path)
    try:
        wait_for(lambda: moving(emulator), 60.0)
        n_before = len(emulator.commands)
        guards = children(body.pid)
        body.send_signal(signal.SIGTERM)
        assert body.wait(timeout=10) == 0
        wait_for(lambda: all(gone(g) for g in guards), 5.0)  # released: no guard left
        after = [line for _, line in list(emulator.commands)[n_before:] if line.startswith(b"D")]
        assert after and after[-1] == b"D,0,0" and not moving(emulator)
        assert hub.wait(timeout=30) == 2  # the hub ends the run: its body went away
    finally:
        end(hub, body)


def test_the_robot_link_dying_mid_run_ends_the_run_as_a_fault_with_its_record(
    bus_overrides, tmp_path
):
    emu = neuvision("emulate", "khepera", "--baud", "115200", stdout=subprocess.PIPE,
                    stderr=subprocess.DEVNULL, text=True)  # fmt: skip
    port = emu.stdout.readline().strip()
    run = neuvision(
        "run", HYBRID, "--quiet", "--duration-s", "60", "--runs-dir", str(tmp_path),
        *sets(bus_overrides, port), stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        wait_for(lambda: any(tmp_path.glob("*/body.log")), 60.0)
        body_log = next(tmp_path.glob("*/body.log"))
        wait_for(lambda: "took run" in body_log.read_text(), 60.0)
        time.sleep(1.0)  # a second of the run
        emu.kill()
        assert run.wait(timeout=30) == 2
        stderr = run.stderr.read()
        assert "run failed" in stderr and "body" in stderr
        log = body_log.read_text()
        assert "serial link" in log and "failed" in log
        record = read_run(body_log.parent)
        assert record.manifest["outcome"] == "fault"
        assert record.manifest["steps"] > 0
    finally:
        end(run, emu)


def test_the_runner_killed_outright_takes_its_local_processes_with_it(
    emulator, bus_overrides, tmp_path
):
    run = neuvision(
        "run", HYBRID, "--quiet", "--duration-s", "60", "--runs-dir", str(tmp_path),
        *sets(bus_overrides, emulator.path), stderr=subprocess.DEVNULL,
    )  # fmt: skip
    endpoints = []
    try:
        wait_for(lambda: moving(emulator), 60.0)
        endpoints = children(run.pid)
        assert len(endpoints) == 3  # the body, the culture and the burst observer
        run.kill()
        killed = time.monotonic()
        wait_for(lambda: not moving(emulator), 5.0)
        assert motor_commands(emulator)[-1][1] == b"D,0,0"
        assert time.monotonic() - killed <= WATCHDOG_S + 0.2
        wait_for(lambda: all(gone(p) for p in endpoints), 15.0)  # none left behind
    finally:
        end(run)
        for pid in endpoints:
            if not gone(pid):
                os.kill(pid, signal.SIGKILL)
