"""`neuvision dashboard` and `run --dashboard` on the command line: what they say and do."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import urllib.request

import pytest

from dashboard.server import bind
from hub.cli import main
from hub.record import write_manifest
from tests.dashboard.synthetic import write_run


def test_a_replay_of_no_run_folder_is_one_line_and_status_3(tmp_path, capsys):
    assert main(["dashboard", "--replay", str(tmp_path / "nothing")]) == 3
    assert capsys.readouterr().err.strip().endswith("not found")
    write_manifest(tmp_path, {"format": "neuvision-run", "outcome": "fault"})
    assert main(["dashboard", "--replay", str(tmp_path)]) == 3
    assert "holds no body reading to replay" in capsys.readouterr().err


def test_a_port_taken_is_one_line_and_status_2(tmp_path, capsys):
    write_run(tmp_path / "run")
    sock = bind("127.0.0.1", 0)
    try:
        port = sock.getsockname()[1]
        assert main(["dashboard", "--replay", str(tmp_path / "run"), "--port", str(port)]) == 2
    finally:
        sock.close()
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"neuvision: cannot serve the dashboard on 127.0.0.1:{port}")


def test_a_host_that_is_not_this_machines_is_bad_input_status_3(tmp_path, capsys):
    write_run(tmp_path / "run")
    # TEST-NET-1 (RFC 5737): never a local address; bind() refuses it at once, sends nothing
    code = main(["dashboard", "--replay", str(tmp_path / "run"), "--host", "192.0.2.1"])
    assert code == 3
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "cannot serve the dashboard on 192.0.2.1" in line and "--host" in line


def test_run_with_a_dashboard_on_a_port_taken_stops_before_anything_starts(tmp_path, capsys):
    sock = bind("127.0.0.1", 0)
    try:
        port = sock.getsockname()[1]
        code = main(
            ["run", "--dashboard", "--runs-dir", str(tmp_path), "--set", f"dashboard.port={port}"]
        )
    finally:
        sock.close()
    assert code == 3
    assert "config error: dashboard.port: cannot serve on 127.0.0.1" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # no run folder, no process


def test_neuvision_dashboard_serves_a_replay_until_sigterm(tmp_path):
    write_run(tmp_path / "run")
    proc = subprocess.Popen(
        [sys.executable, "-m", "hub.cli", "dashboard", "--replay", str(tmp_path / "run")]
        + ["--port", "0", "--speed", "4"],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stderr.readline()  # the first line says where
        url = re.search(r"dashboard at (http://\S+)", line).group(1)
        assert "replay of" in line
        frame = json.loads(urllib.request.urlopen(url + "frame", timeout=10).read())
        assert frame["source"]["kind"] == "replay" and frame["replay"]["speed"] == 4.0
    finally:
        proc.send_signal(signal.SIGTERM)
        rest = proc.communicate(timeout=20)[1]
    assert proc.returncode == 0, rest


def _policies(pid: int) -> set[int]:
    """The scheduling policy of every thread of process ``pid``."""
    return {os.sched_getscheduler(int(tid)) for tid in os.listdir(f"/proc/{pid}/task")}


@pytest.mark.parametrize(
    "yield_cpu, policy",
    [("true", "SCHED_IDLE"), pytest.param("false", "SCHED_OTHER", marks=pytest.mark.slow)],
)
def test_a_live_dashboard_takes_the_cpu_only_when_the_run_leaves_it_idle(
    bus_overrides, yield_cpu, policy
):
    sets = [a for o in bus_overrides for a in ("--set", o)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "hub.cli", "dashboard", "--port", "0", *sets]
        + ["--set", f"dashboard.yield_cpu={yield_cpu}"],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        # where, and how it is scheduled (after a line that no hub is there yet)
        line = next(ln for ln in proc.stderr if "dashboard at" in ln)
        url = re.search(r"dashboard at (http://\S+)", line).group(1)
        if "SCHED_IDLE refused" in line:
            pytest.skip(f"this machine refuses SCHED_IDLE: {line.strip()}")
        assert ("scheduling idle" in line) == (yield_cpu == "true"), line
        urllib.request.urlopen(url, timeout=10).read()  # serving, its threads all started
        assert _policies(proc.pid) == {getattr(os, policy)}
    finally:
        proc.send_signal(signal.SIGTERM)
        rest = proc.communicate(timeout=20)[1]
    assert proc.returncode == 0, rest
