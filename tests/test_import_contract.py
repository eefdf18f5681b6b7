"""The layers import only downward (ARCHITECTURE.md "Folders"; issue 15 item 4).

Every module's imports are read with ``ast`` (nothing is imported, so no side effects), local
imports inside functions included -- a wrong-way import cannot hide in a function body. String
references (``hub.launch`` names endpoint classes as ``"sim_robot.endpoint:ArenaEndpoint"``) are
not imports and are fine. The rules, from the bottom up:

- ``settings``, ``devices``: import nothing of the project;
- ``hub.analysis`` (plain numpy spike analysis): only itself, ``settings``, ``devices``;
- ``sim_network``, ``sim_robot`` (the models): no ``hub``, ``lab``, ``adapters``, nor each
  other -- except their ``endpoint.py``, which may import the hub's contract, endpoint base
  and config (``hub.protocol``, ``hub.endpoint``, ``hub.config``, ``hub.wire``);
- ``hub``: no simulator, ``lab`` or ``adapters``; ``hub/cli.py``, the ``neuvision`` command,
  may import ``lab`` and ``adapters``, whose commands it dispatches to;
- ``adapters``: ``hub``, ``devices``, ``settings``, not the simulators or ``lab`` -- except
  an emulator (``adapters/<device>/emulator.py``), a device played by a simulator;
- ``lab``: anything but ``adapters``;
- ``dashboard`` (the live page and replay): anything but ``adapters``, like ``lab`` (it
  reads a run's world through ``lab.behaviour``); only ``hub/cli.py`` imports it;
- ``neuvision`` (the Python API): anything.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = (
    "settings", "devices", "hub", "sim_network", "sim_robot", "adapters", "lab", "neuvision",
    "dashboard",
)  # fmt: skip
SIMULATORS = ("sim_network", "sim_robot")
ENDPOINT_MAY_IMPORT = ("hub.protocol", "hub.endpoint", "hub.config", "hub.wire")


def module_name(root: Path, path: Path) -> str:
    """``hub/analysis/spikes.py`` -> ``hub.analysis.spikes`` (a package's ``__init__`` -> it)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports(root: Path, path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in a file, relative ones resolved."""
    tree = ast.parse(path.read_text(), filename=str(path))
    me = module_name(root, path).split(".")
    package = me if path.name == "__init__.py" else me[:-1]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module
            # ``from hub import protocol`` imports hub.protocol
            found += [(node.lineno, f"{target}.{alias.name}") for alias in node.names]
    return found


def _within(name: str, *prefixes: str) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def allowed(importer: str, imported: str) -> bool:
    """Whether module ``importer`` may import ``imported`` (both dotted, absolute)."""
    layer = importer.split(".")[0]
    target = imported.split(".")[0]
    if target not in PACKAGES or target == layer and layer != "hub":
        return True  # third-party, standard library, or the package itself
    if layer in ("settings", "devices"):
        return False
    if layer in SIMULATORS:
        if importer == f"{layer}.endpoint":
            return _within(imported, *ENDPOINT_MAY_IMPORT, "settings", "devices")
        return target in ("settings", "devices")
    if layer == "hub":
        if _within(importer, "hub.analysis"):
            return _within(imported, "hub.analysis", "settings", "devices")
        if importer == "hub.cli" and target in ("lab", "adapters", "dashboard"):
            return True
        return target in ("hub", "settings", "devices")
    if layer == "adapters":
        if importer.endswith(".emulator") and target in SIMULATORS:
            return True
        return target in ("hub", "settings", "devices")
    if layer in ("lab", "dashboard"):
        return target != "adapters"
    if layer == "neuvision":  # the Python API: the top, re-exporting lab and hub
        return True
    raise AssertionError(f"no rule for the layer {layer!r}")


def violations(root: Path) -> list[str]:
    """Every import in the project's packages under ``root`` that breaks the rules."""
    out = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            importer = module_name(root, path)
            for line, imported in imports(root, path):
                if not allowed(importer, imported):
                    out.append(f"{path.relative_to(root)}:{line}: {importer} imports {imported}")
    return out


def test_the_project_imports_only_downward():
    assert violations(ROOT) == []


def test_the_check_sees_the_layers_it_guards():
    modules = {module_name(ROOT, p) for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}
    for expected in ("hub.loop", "hub.analysis.metrics", "sim_network.network", "sim_robot.arena",
                     "sim_network.endpoint", "lab.reproduce", "devices.khepera"):  # fmt: skip
        assert expected in modules


PLANTED = {
    # the old cycle: a simulator reaching up into the hub, hidden in a function
    "sim_network/activity.py": "def f():\n    from hub.analysis.metrics import analyze\n",
    # a hub module reaching into a simulator (relative imports resolve too)
    "hub/postrun.py": "import sim_robot.metrics\n",
    # the plain analysis depending on the hub's run record
    "hub/analysis/run.py": "from ..record import read_run\n",
    # an adapter taking a shortcut through a simulator's constants
    "adapters/khepera.py": "from sim_robot import bodies\n",
    # devices must stay at the bottom
    "devices/mea.py": "from sim_network.config import MeaConfig\n",
    # a simulator's endpoint may use the contract, not the hub's loop
    "sim_robot/endpoint.py": "from hub.protocol import Description\nfrom hub.loop import Hub\n",
    # the lab may use everything but the device adapters
    "lab/compare.py": "import hub.record, sim_robot, sim_network\nfrom adapters import khepera\n",
    # the hub's loop knows nothing of its observers' pages
    "hub/loop.py": "from dashboard.state import FrameState\n",
    # the dashboard watches the bus; it never drives a device itself
    "dashboard/observer.py": "import hub.ctl, lab.behaviour\nfrom adapters.mea import driver\n",
}


@pytest.mark.parametrize("path", sorted(PLANTED))
def test_the_check_fails_on_a_planted_wrong_way_import(tmp_path, path):
    for package in PACKAGES:
        (tmp_path / package).mkdir()
        (tmp_path / package / "__init__.py").write_text("")
    (tmp_path / "hub" / "analysis").mkdir()
    (tmp_path / path).write_text(PLANTED[path])
    found = violations(tmp_path)
    assert len(found) == 1 and found[0].startswith(path + ":"), found


def test_what_each_layer_may_import():
    assert allowed("sim_network.endpoint", "hub.endpoint.Endpoint")
    assert allowed("sim_robot.bodies", "devices.khepera")
    assert not allowed("sim_robot.bodies", "sim_network.config")
    assert allowed("hub.loop", "hub.analysis.bursts.BurstParams")
    assert allowed("hub.cli", "lab.postrun.after_run")
    assert not allowed("hub.launch", "lab.postrun")
    assert allowed("lab.reproduce", "sim_network.Network")
    assert allowed("adapters.khepera", "devices.khepera")
    assert allowed("settings.load", "tomllib")
    assert allowed("dashboard.scene", "lab.behaviour.world_of")
    assert allowed("hub.cli", "dashboard.app.run_dashboard")
    assert not allowed("hub.launch", "dashboard.app")
