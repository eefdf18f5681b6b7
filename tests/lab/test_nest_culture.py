"""The culture on NEST against the culture on sim_network (issue 22's checks).

Two tiers, both of the default culture (on NEST through NeuVision's NEST module). Slow
(CI, ~25 s): half a minute of spontaneous activity of both backends, and the paper's
one-neuron protocol on NEST. Long (``NEUVISION_LONG=1``, ~7 min on a 2-core machine; the
figures they give are in docs/nest.md): 300 s of spontaneous activity of both, MFR, MBR,
MNBR and network-burst duration within 15 %; and the closed loop with the NEST culture
through ``neuvision compare``, feedback against blind over 4 seeds. All skip,
saying why, where NEST is not installed or its module cannot be built.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from lab import backends
from sim_network import load_config

#: The culture compared: main's default culture (repoint it when the default changes); on
#: NEST it takes NeuVision's NEST module (its adaptation and slow current).
CULTURE = "configs/culture_1024.toml"

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("module_built")]
long_check = pytest.mark.skipif(
    os.environ.get("NEUVISION_LONG") != "1",
    reason="long (minutes on 2 cores): NEUVISION_LONG=1 runs it (figures in docs/nest.md)",
)


def test_both_backends_fire_alike_over_half_a_minute():
    cfg = load_config(CULTURE)
    sim = backends.spontaneous(backends.build("sim_network", cfg, 1), 30.0, 2.0)
    nest = backends.spontaneous(backends.build("nest", cfg, 1), 30.0, 2.0)
    assert nest["mfr_hz"] == pytest.approx(sim["mfr_hz"], rel=0.05)
    assert nest["mfr_inh_hz"] == pytest.approx(sim["mfr_inh_hz"], rel=0.05)
    # excitatory spikes come mostly in the few network bursts of half a minute: counted,
    # not compared (the 300 s check below compares their rates)
    assert nest["n_network_bursts"] >= 1 and sim["n_network_bursts"] >= 1


def test_one_stimulated_neuron_evokes_a_psth_peak_at_30_to_100_ms_on_nest():
    net = backends.build("nest", load_config(CULTURE), 1)
    out = backends.evoked(net, seconds=60.0, warmup_s=2.0)  # 12 pulses, 5 s apart
    assert out["n_pulses"] == 12
    assert out["psth_peak_in_range"], out
    assert out["psth_peak_hz"] > 2 * out["psth_baseline_hz"]


@long_check
@pytest.mark.timeout(1800)  # over pytest's 5 minutes on a slower host
def test_300_s_of_spontaneous_activity_agree_within_15_percent():
    out = backends.compare(load_config(CULTURE), seed=1, seconds=300.0)
    assert all(out["within"].values()), out["difference"]


@long_check
@pytest.mark.bus
@pytest.mark.timeout(3600)  # eight 60 s runs: ~5 min here, over pytest's 5 minutes
def test_the_closed_loop_on_nest_avoids_obstacles_better_than_blind(tmp_path):
    out = tmp_path / "cmp"
    cmd = [
        sys.executable, "-m", "hub.cli", "compare", "configs/closed_loop.toml",
        "configs/closed_loop_blind.toml", "--seeds", "4", "--jobs", "1", "--out", str(out),
        "--set", 'culture.kind="nest"',
    ]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=3000)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads((out / "compare.json").read_text())
    assert all(run["ok"] for run in result["runs"]) and len(result["runs"]) == 8
    stats = result["stats"]
    feedback, blind = (stats[name] for name in ("closed_loop", "closed_loop_blind"))
    assert feedback["obstacle_entries"]["mean"] < blind["obstacle_entries"]["mean"]
