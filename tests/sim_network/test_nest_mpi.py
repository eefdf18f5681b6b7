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


pytestmark = pytest.mark.skipif(_why_not() is not None, reason=_why_not() or "")

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
    net.close()
    print(json.dumps({"ranks": net.n_ranks, "channel": first[0], "t_ms": first[1],
                      "v": len(v), "again": again}))
    """
)


def run_ranks(n: int, threads_env: dict | None = None) -> dict:
    out = subprocess.run(
        ["mpirun", "-n", str(n), sys.executable, "-c", SCRIPT],
        capture_output=True, text=True, timeout=600, cwd=ROOT,
        env={**os.environ, "PYTHONPATH": ROOT, **(threads_env or {})},
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_two_ranks_gather_each_step_s_spikes_to_rank_0():
    two = run_ranks(2)
    assert two["ranks"] == 2 and two["v"] == 144
    assert 5 in two["channel"]  # the pulse of step 2 made neuron 5 fire
    assert sorted(two["t_ms"]) == two["t_ms"]  # in time order, as one process gives them
    # a run from the network as built repeats the first 300 ms spike for spike
    assert two["again"] == [two["channel"], two["t_ms"]]
