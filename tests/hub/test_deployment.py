"""Parts started separately, as on several hosts: endpoints that wait for their hub and say
so, serve one run after another (or one, with --once), and a one-line error when the hub
cannot be reached. Real processes, real Zenoh on loopback."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from hub.record import read_run
from tests.harness import wait_for

pytestmark = pytest.mark.bus
CONFIG = "configs/closed_loop.toml"
EXTERNAL = ['body.launch="external"', 'culture.launch="external"']


def neuvision(*args, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "hub.cli", *args], text=True, **kw)


def sets(items) -> list[str]:
    return [a for item in items for a in ("--set", item)]


def port_of(bus_overrides) -> str:
    listen = next(i for i in bus_overrides if i.startswith("bus.listen="))
    return json.loads(listen.split("=", 1)[1])[0].rsplit(":", 1)[1]


@pytest.mark.slow
def test_endpoints_wait_for_their_hub_then_serve_run_after_run(tmp_path, bus_overrides):
    items = [*bus_overrides, *EXTERNAL]
    port = port_of(bus_overrides)
    session = [i for i in bus_overrides if i.startswith("bus.session")]
    logs = {role: open(tmp_path / f"{role}.log", "w") for role in ("body", "culture")}
    endpoints = {
        role: neuvision("endpoint", role, CONFIG, "--connect", f"127.0.0.1:{port}",
                        *sets(session + ["bus.scouting=false"]), stderr=logs[role])
        for role in ("body", "culture")
    }  # fmt: skip
    try:
        # started before the hub: each says where it is trying, and keeps saying it
        wait_for(
            lambda: "waiting for the hub at tcp/127.0.0.1:" in (tmp_path / "body.log").read_text(),
            20,
        )
        for n in (1, 2):  # two runs of a hub against the same endpoints
            hub = subprocess.run(
                [sys.executable, "-m", "hub.cli", "hub", CONFIG, "--quiet", "--duration-s", "0.5",
                 "--runs-dir", str(tmp_path / f"runs{n}"), *sets(items)],
                capture_output=True, text=True, timeout=120,
            )  # fmt: skip
            assert hub.returncode == 0, hub.stderr[-2000:]
            (run_dir,) = (tmp_path / f"runs{n}").iterdir()
            m = read_run(run_dir).manifest
            assert m["outcome"] == "completed" and m["steps"] == 50
            assert m["endpoints"]["body"]["runs"] == n  # the same process, its n-th run
            host = m["endpoints"]["culture"]["host"]
            assert host["pid"] == endpoints["culture"].pid and host["hostname"]
            assert abs(m["endpoints"]["body"]["clock_offset_ms"]) < 1000
        assert all(p.poll() is None for p in endpoints.values())  # still serving
    finally:
        for p in endpoints.values():
            p.terminate()
        codes = [p.wait(timeout=20) for p in endpoints.values()]
        for f in logs.values():
            f.close()
    assert codes == [0, 0]


@pytest.mark.slow  # a whole run
def test_an_endpoint_with_once_exits_when_its_run_ends(tmp_path, bus_overrides):
    items = [*bus_overrides, *EXTERNAL]
    endpoints = [
        neuvision("endpoint", role, CONFIG, "--once", *sets(bus_overrides),
                  stderr=subprocess.DEVNULL)
        for role in ("body", "culture")
    ]  # fmt: skip
    hub = subprocess.run(
        [sys.executable, "-m", "hub.cli", "hub", CONFIG, "--quiet", "--duration-s", "0.3",
         "--runs-dir", str(tmp_path), *sets(items)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    try:
        assert hub.returncode == 0, hub.stderr[-2000:]
        assert [p.wait(timeout=20) for p in endpoints] == [0, 0]
    finally:
        for p in endpoints:
            if p.poll() is None:
                p.kill()


def test_a_hub_that_cannot_be_reached_is_one_line(bus_overrides):
    done = subprocess.run(
        [sys.executable, "-m", "hub.cli", "endpoint", "body", CONFIG,
         *sets([*bus_overrides, "bus.connect_timeout_s=1.0"])],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith("neuvision: cannot reach the hub at tcp/127.0.0.1:")
    assert "within 1 s (bus.connect_timeout_s)" in last


@pytest.mark.slow  # a whole run
def test_a_folder_holding_another_copy_of_a_package_does_not_shadow_the_installed_one(
    tmp_path, bus_overrides
):
    # run from a clone of another version: its modules must not mix with the installed
    # ones, in the command's process or in the endpoints it starts
    shadow = tmp_path / "sim_robot"
    shadow.mkdir()
    (shadow / "__init__.py").write_text('raise ImportError("the folder\'s copy was imported")\n')
    config = str((Path(__file__).parents[2] / CONFIG).resolve())
    done = subprocess.run(
        [sys.executable, "-m", "hub.cli", "run", config, "--quiet", "--duration-s", "0.2",
         "--runs-dir", str(tmp_path / "runs"), *sets(bus_overrides)],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
        env={**os.environ, "PYTHONSAFEPATH": "1"},  # as the installed `neuvision` script
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert "the folder's copy" not in done.stderr
