"""Ctrl-C (SIGINT) or SIGTERM before the first step, while the hub waits for its endpoints,
ends the run as an interruption, as during the steps: exit status 130, outcome
``interrupted`` in the manifest, the local endpoints stopped."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from hub.cli import EXIT_INTERRUPTED
from tests.conftest import TEST_ENDPOINTS


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
