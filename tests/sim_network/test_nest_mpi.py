"""The NEST culture across MPI ranks: every rank builds its share, rank 0 gathers each
step's spikes. Runs only where NEST is built with MPI and ``mpirun`` and mpi4py are present
(the nest-simulator wheel has no MPI: docs/nest.md says how to build one that has)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap

import pytest

from sim_network import nest_backend as nb

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _nest_has_mpi() -> bool:
    if not nb.nest_available():
        return False
    probe = (
        "import os; os.environ['PYNEST_QUIET'] = '1'; import nest; "
        "print(nest.build_info['have_mpi'])"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    return out.stdout.strip().endswith("True")


def _why_not() -> str | None:
    if not nb.nest_available():
        return f"NEST is not installed: {nb.INSTALL_HINT}"
    if shutil.which("mpirun") is None:
        return "no mpirun on PATH"
    try:
        import mpi4py  # noqa: F401
    except ImportError:
        return "mpi4py is not installed"
    if not _nest_has_mpi():
        return "this NEST is built without MPI (the nest-simulator wheel is; docs/nest.md)"
    return None


pytestmark = [
    pytest.mark.skipif(_why_not() is not None, reason=_why_not() or ""),
    pytest.mark.bus,
]

SCRIPT = textwrap.dedent(
    """
    import json, sys
    import numpy as np
    from sim_network import LayoutConfig, NetworkConfig, Pulses
    from sim_network.nest_backend import NestNetwork
    net = NestNetwork(NetworkConfig(layout=LayoutConfig(rows=12, cols=12)), seed=3)
    if net.rank != 0:
        net.follow()
        sys.exit(0)
    def steps():
        parts = [net.run(10.0, Pulses.single([5], 100.0, 10.0) if k == 2 else None)
                 for k in range(30)]
        return [np.concatenate([p.channel for p in parts]).tolist(),
                np.concatenate([p.t_ms for p in parts]).tolist()]
    first = steps()
    v = net.potentials()
    net.set_state({"step": np.array(0)})
    again = steps()
    connections = net.n_connections
    net.close()
    print(json.dumps({"ranks": net.n_ranks, "channel": first[0], "t_ms": first[1],
                      "v": len(v), "again": again, "connections": connections,
                      "synapses": net.synapses.n_synapses}))
    """
)


def mpi_env() -> dict:
    path = os.pathsep.join(p for p in (ROOT, os.environ.get("PYTHONPATH", "")) if p)
    return {
        **os.environ,
        "PYTHONPATH": path,
        # Open MPI: as root in a container, and more ranks than cores on a small machine
        "OMPI_ALLOW_RUN_AS_ROOT": "1",
        "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
        "OMPI_MCA_rmaps_base_oversubscribe": "1",
    }


def run_ranks(n: int) -> dict:
    out = subprocess.run(
        ["mpirun", "-n", str(n), sys.executable, "-c", SCRIPT],
        capture_output=True, text=True, timeout=600, cwd=ROOT, env=mpi_env(),
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_two_ranks_gather_each_step_s_spikes_to_rank_0():
    one, two = run_ranks(1), run_ranks(2)
    assert one["ranks"] == 1 and two["ranks"] == 2 and two["v"] == 144
    assert two["connections"] == one["connections"] == two["synapses"]  # all ranks together
    assert 5 in two["channel"]  # the pulse of step 2 made neuron 5 fire
    # the culture's noise draws nothing from NEST: two ranks give one process's spikes
    assert [two["channel"], two["t_ms"]] == [one["channel"], one["t_ms"]]
    # a run from the network as built repeats the first 300 ms spike for spike
    assert two["again"] == [two["channel"], two["t_ms"]]


def test_the_culture_endpoint_serves_from_rank_0_under_mpirun(tmp_path, bus_overrides):
    from hub.record import read_run
    from tests.harness import wait_for

    listen = next(i for i in bus_overrides if i.startswith("bus.listen="))
    port = json.loads(listen.split("=", 1)[1])[0].rsplit(":", 1)[1]
    items = [
        *bus_overrides, 'culture.launch="external"', 'culture.kind="nest"',
        'culture.params.config="configs/culture_1024_local.toml"',
        "culture.params.layout.rows=16", "culture.params.layout.cols=16",
    ]  # fmt: skip
    sets = [a for item in items for a in ("--set", item)]
    log = open(tmp_path / "culture.log", "w")
    culture = subprocess.Popen(
        ["mpirun", "-n", "2", sys.executable, "-m", "hub.cli", "endpoint", "culture",
         "configs/closed_loop.toml", "--connect", f"127.0.0.1:{port}", "--once", *sets],
        cwd=ROOT, env=mpi_env(), stdout=log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        wait_for(lambda: "waiting for the hub" in (tmp_path / "culture.log").read_text(), 120)
        hub = subprocess.run(
            [sys.executable, "-m", "hub.cli", "run", "configs/closed_loop.toml", "--quiet",
             "--duration-s", "1.0", "--runs-dir", str(tmp_path / "runs"), *sets],
            capture_output=True, text=True, timeout=300, cwd=ROOT, env=mpi_env(),
        )  # fmt: skip
        assert hub.returncode == 0, hub.stderr[-2000:]
        (run_dir,) = (tmp_path / "runs").iterdir()
        manifest = read_run(run_dir).manifest
        assert manifest["outcome"] == "completed" and manifest["steps"] == 100
        assert manifest["endpoints"]["culture"]["host"]["pid"] != culture.pid  # rank 0
        # --once: rank 0 stops serving when the run ends and releases the other rank
        code = culture.wait(timeout=120)
    finally:
        if culture.poll() is None:
            culture.kill()
        log.close()
    assert code == 0, (tmp_path / "culture.log").read_text()[-3000:]
