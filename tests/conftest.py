"""Fixtures shared by the bus tests: an isolated Zenoh namespace on loopback per test."""

from __future__ import annotations

import json
import os
import secrets
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from hub.bus import free_tcp_port

# Shared 2-core machines: judge properties, not the speed of example generation.
settings.register_profile("neuvision", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("neuvision")


@pytest.fixture
def bus_overrides() -> list[str]:
    """Config overrides that isolate a test: random session, free loopback port, no scouting."""
    session = f"test-{secrets.token_hex(4)}"
    port = free_tcp_port()
    return [
        f"bus.session={json.dumps(session)}",
        f'bus.listen=["tcp/127.0.0.1:{port}"]',
        "bus.scouting=false",
    ]


@pytest.fixture(scope="session")
def module_built() -> Path:
    """NeuVision's NEST module (sim_network/nest_module.py), built once per source version,
    or the test skipped saying why: NEST missing, or no C++ compiler or boost and libltdl
    headers to build it (CI installs them)."""
    from sim_network import nest_backend, nest_module

    if not nest_backend.nest_available():
        pytest.skip(f"NEST is not installed: {nest_backend.INSTALL_HINT}")
    try:
        return nest_module.module_path()
    except nest_module.NestModuleError as exc:
        pytest.skip(str(exc))


TEST_ENDPOINTS = [
    'body.kind="tests.endpoints:EchoBody"',
    'culture.kind="tests.endpoints:EchoCulture"',
    'coding.scheme="tests.endpoints:code_step_count"',
    'decoding.scheme="tests.endpoints:decode_step"',
    # The trivial culture has no bursts worth detecting: no burst observer, a second of
    # CPU less per run (tests/hub/test_burst_observer.py turns it on).
    "online.enabled=false",
]


# Endpoint subprocesses import the test fixtures (tests.endpoints) from the repo root.
ROOT = str(Path(__file__).resolve().parent.parent)
os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (ROOT, os.environ.get("PYTHONPATH", "")) if p)

# Hubs that `neuvision run` starts say where they listen in a folder of the user's
# (hub/local_hubs.py): the tests' hubs in one of their own, never seen by a user's commands.
RUNTIME_DIR = tempfile.TemporaryDirectory(prefix="nv-test-hubs-")
os.environ["NEUVISION_RUNTIME_DIR"] = RUNTIME_DIR.name

# LSL (adapters/mea/lsl.py) finds streams by multicast: every test, and every endpoint a
# test starts, keeps it on this machine's loopback.
os.environ["LSLAPICFG"] = str(Path(ROOT) / "adapters" / "mea" / "lsl_loopback.cfg")
