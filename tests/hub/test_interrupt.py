"""Ctrl-C (SIGINT) or SIGTERM before the first step, while the hub waits for its endpoints,
ends the run as an interruption, as during the steps: exit status 130, outcome
``interrupted`` in the manifest, the local endpoints stopped."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from hub.cli import EXIT_INTERRUPTED
from tests.conftest import TEST_ENDPOINTS
from tests.harness import wait_for


def _processes_naming(text: str) -> list[str]:
    """The command lines of this machine's processes that contain ``text``."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            line = cmdline.read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:  # ended meanwhile
            continue
        if text in line:
            found.append(line)
    return found


@pytest.mark.parametrize(
    "sig",
    [
        pytest.param(signal.SIGINT, id="SIGINT"),
        pytest.param(signal.SIGTERM, id="SIGTERM", marks=pytest.mark.slow),  # SIGINT's path
        # the terminal closed (a window shut, ssh dropped): it left an unfinished run
        pytest.param(signal.SIGHUP, id="SIGHUP"),
    ],
)
def test_a_signal_while_waiting_for_the_endpoints_interrupts_the_run(tmp_path, bus_overrides, sig):
    # The culture is started elsewhere and never comes: the hub waits for it.
    sets = [*TEST_ENDPOINTS, *bus_overrides, "culture.launch=external"]
    session = json.loads(bus_overrides[0].split("=", 1)[1])
    argv = [sys.executable, "-m", "hub.cli", "run", "--quiet", "--runs-dir", str(tmp_path)]
    proc = subprocess.Popen(
        [*argv, *(a for s in sets for a in ("--set", s)), "--duration-s", "5"],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        for line in proc.stderr:  # the hub says what it waits for
            if "waiting for" in line:
                break
        proc.send_signal(sig)
        stderr = proc.stderr.read()
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == EXIT_INTERRUPTED, stderr
    assert "run failed" not in stderr and "Traceback" not in stderr, stderr
    assert "neuvision: interrupted after 0 steps" in stderr
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert (manifest["outcome"], manifest["reason"], manifest["steps"]) == (
        "interrupted",
        "interrupted",
        0,
    )
    assert "endpoint exited with status" not in stderr, "an endpoint did not stop cleanly"
    assert _processes_naming(session) == [], "a local endpoint is still running"


@pytest.mark.parametrize(
    "where, seen",
    [
        # the KeyboardInterrupt raised for the signal is printed as ignored and lost
        ("ctypes", "Exception ignored on calling ctypes callback"),
        # CPython 3.11 notes it as unhandled, though caught, and would exit by SIGINT
        ("exec", "neuvision: interrupted\n"),
        # a library turns it into an error of its own
        ("error", "neuvision: interrupted (RuntimeError: a library's own error)"),
    ],
)
def test_an_endpoint_stopped_while_it_starts_exits_cleanly_without_connecting(
    bus_overrides, where, seen
):
    sets = [
        'body.kind="tests.endpoints:BodyStoppedWhileBuilding"',
        f'body.params.where="{where}"',
        *bus_overrides,
    ]
    proc = subprocess.run(
        [sys.executable, "-m", "hub.cli", "endpoint", "body"]
        + [a for s in sets for a in ("--set", s)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert seen in proc.stderr
    assert proc.returncode == 0, proc.stderr
    assert "connecting to the hub" not in proc.stderr, proc.stderr


def test_sigterm_while_a_run_starts_up_is_an_interrupt_not_a_death_by_signal():
    # before the run's own handler is in (its imports, its checks): it died by the
    # signal (status 143, nothing said) where Ctrl-C gave "interrupted", 130
    program = (
        "import os, signal, sys, time\n"
        "import hub.cli\n"
        "def starting(args):\n"
        "    os.kill(os.getpid(), signal.SIGTERM)\n"
        "    time.sleep(10)\n"
        "hub.cli.COMMANDS['run'] = starting\n"
        "sys.exit(hub.cli.main(['run']))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", program], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == EXIT_INTERRUPTED, done.stderr
    assert done.stderr.strip().endswith("neuvision: interrupted")


def test_the_terminal_closing_mid_run_interrupts_it_cleanly(tmp_path, bus_overrides):
    # a closed terminal sends SIGHUP to the whole job: the run and the endpoints it started
    sets = [*TEST_ENDPOINTS, *bus_overrides]
    argv = [sys.executable, "-m", "hub.cli", "run", "--quiet", "--runs-dir", str(tmp_path)]
    proc = subprocess.Popen(
        [*argv, *(a for s in sets for a in ("--set", s)), "--duration-s", "600"],
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # a job of its own, as a shell makes it
    )
    try:
        wait_for(
            lambda: any(p.stat().st_size > 20_000 for p in tmp_path.glob("*/record.nvrec")), 60
        )
        os.killpg(proc.pid, signal.SIGHUP)
        stderr = proc.stderr.read()
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == EXIT_INTERRUPTED, stderr
    assert "endpoint exited with status" not in stderr, stderr
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert (manifest["outcome"], manifest["reason"]) == ("interrupted", "interrupted")
    assert manifest["steps"] > 0
