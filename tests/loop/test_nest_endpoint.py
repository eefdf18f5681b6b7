"""The culture on NEST served on the bus (``culture.kind = "nest"``): with the real hub over
Zenoh, through the conformance suite, and refused before anything starts when it asks for
what NEST cannot express. Tests that need NEST skip, saying so, where it is not installed."""

from __future__ import annotations

import numpy as np
import pytest

from hub import conformance
from hub.config import ConfigError, load_config
from hub.protocol import SpikeBatch
from sim_network import AdaptationConfig, LayoutConfig, NetworkConfig, SlowCurrentConfig
from sim_network import nest_backend as nb
from sim_network.endpoint import NestEndpoint
from tests.harness import harness

needs_nest = pytest.mark.skipif(
    not nb.nest_available(), reason=f"NEST is not installed: {nb.INSTALL_HINT}"
)
#: The closed loop's culture on NEST in the tests on the bus: the culture before issue 21,
#: which NEST's own izhikevich expresses (the default culture takes NeuVision's NEST module,
#: tested in tests/sim_network/test_nest_backend.py).
NEST_CULTURE = ['culture.kind="nest"', 'culture.params.config="configs/culture_1024_local.toml"']
NEST = [*NEST_CULTURE, "culture.params.seed=3"]


def test_a_culture_nest_cannot_express_is_refused_by_name_before_anything_starts():
    cfg = load_config(
        "configs/closed_loop.toml", [*NEST_CULTURE, 'culture.params.neurons.model="hh"']
    )
    with pytest.raises(ConfigError, match=r"culture.params.neurons.model = 'hh'"):
        cfg.resolved()
    stdp = ["culture.params.stdp.enabled=true"]  # with the default culture's depression
    cfg = load_config("configs/closed_loop.toml", ['culture.kind="nest"', *stdp])
    with pytest.raises(ConfigError, match=r"culture.params.stdp.enabled with depression.u"):
        cfg.resolved()
    cfg = load_config("configs/closed_loop.toml", [*NEST, 'culture.params.noise_source="gauss"'])
    with pytest.raises(ConfigError, match="culture.params.noise_source must be one of"):
        cfg.resolved()
    cfg = load_config("configs/closed_loop.toml", [*NEST, "culture.params.thread=2"])
    with pytest.raises(ConfigError, match=r"thread is not a known key \(did you mean threads\?\)"):
        cfg.resolved()


@needs_nest
def test_the_closed_loop_file_takes_the_nest_culture_with_two_overrides():
    cfg = load_config("configs/closed_loop.toml", NEST_CULTURE).resolved()
    params = cfg.culture.params
    assert params["threads"] == 1 and params["noise_source"] == "culture"
    assert params["config"]["layout"]["rows"] == 32  # the culture file, resolved


@pytest.mark.slow  # NEST in the loop, run after run
@needs_nest
@pytest.mark.bus
def test_the_nest_endpoint_answers_a_pulse_in_step_windows_run_after_run(tmp_path, bus_overrides):
    with harness(
        tmp_path,
        bus_overrides,
        *NEST,
        'coding.scheme="tests.endpoints:pulse_at_step"',
        "coding.params.channel=0",
        "coding.params.step=20",
        "experiment.duration_s=0.4",
    ) as h:
        result = h.run()
        first = h.received(SpikeBatch)
        h.run_dir = tmp_path / "again"  # a second run of the same endpoint process
        h.run_dir.mkdir()
        again = h.run()
        second = h.received(SpikeBatch)
    assert result.outcome == again.outcome == "completed"
    desc = result.descriptions["culture"]
    assert desc.kind == "nest" and desc.channel.size == 1024
    assert set(np.unique(desc.cell_type)) == {0, 1}
    assert sorted(first) == list(range(40))
    for k, b in first.items():
        assert b.t0_s == pytest.approx(k * 0.01) and b.t1_s == pytest.approx((k + 1) * 0.01)
        assert np.all((b.t_ms >= 0) & (b.t_ms <= 10.0))
    # 100 µA for 10 ms makes the stimulated neuron fire during that step
    assert 0 in first[20].channel
    # each run starts from the network as built: lockstep runs repeat spike for spike
    for k in first:
        assert np.array_equal(first[k].channel, second[k].channel)
        assert np.array_equal(first[k].t_ms, second[k].t_ms)
    assert h.exit_codes["culture"] == 0


def small_nest_culture() -> NestEndpoint:
    cfg = NetworkConfig(
        layout=LayoutConfig(rows=4, cols=4),
        adaptation=AdaptationConfig(increment_exc_mv_per_ms=0.0),
        slow_current=SlowCurrentConfig(share=0.0),
    )
    return NestEndpoint(nb.NestNetwork(cfg, 1))


@needs_nest
@pytest.mark.parametrize("check", conformance.CHECKS, ids=lambda c: c.__name__)
def test_the_nest_endpoint_keeps_the_contract(check):
    check(small_nest_culture)
