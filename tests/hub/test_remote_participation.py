"""Parts started as docs/remote.md says, by someone who gets a detail wrong: a hub whose
address is taken, an endpoint started with other settings than its hub's. Real processes,
real Zenoh on loopback (scouting off, a random session)."""

from __future__ import annotations

import socket
import subprocess
import sys

import pytest

from hub.record import read_run
from tests.hub.test_deployment import CONFIG, EXTERNAL, port_of, sets

pytestmark = pytest.mark.bus


def test_a_hub_whose_address_is_taken_closes_its_run_folder_as_a_fault(tmp_path, bus_overrides):
    port = int(port_of(bus_overrides))
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as taken:
        taken.bind(("127.0.0.1", port))
        taken.listen(1)
        done = subprocess.run(
            [sys.executable, "-m", "hub.cli", "hub", CONFIG, "--quiet", "--duration-s", "0.2",
             "--runs-dir", str(tmp_path), *sets([*bus_overrides, *EXTERNAL])],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
    assert done.returncode == 2, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith(f"neuvision: cannot listen on tcp/127.0.0.1:{port}")
    (run_dir,) = tmp_path.iterdir()
    m = read_run(run_dir).manifest
    # not left "running" for ever: the run ended, as a fault, and says why
    assert m["outcome"] == "fault"
    assert m["reason"].startswith(f"cannot listen on tcp/127.0.0.1:{port}")
    assert m["steps"] == 0 and m["end_utc"]
