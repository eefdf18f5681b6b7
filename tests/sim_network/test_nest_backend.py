"""The culture on NEST (sim_network/nest_backend.py): built from the same sampler, the same
noise, pulses on the same steps, deterministic in chunks, rebuilt as built; what NEST cannot
express refused by name. Tests that need NEST skip, saying so, where it is not installed."""

from __future__ import annotations

import dataclasses
import threading
from types import SimpleNamespace

import numpy as np
import pytest

from settings import ConfigError
from sim_network import (
    AdaptationConfig,
    ConnectivityConfig,
    DepressionConfig,
    LayoutConfig,
    Network,
    NetworkConfig,
    NeuronConfig,
    NoiseConfig,
    Pulses,
    SlowCurrentConfig,
    Spikes,
    StdpConfig,
    load_config,
    nest_module,
)
from sim_network import nest_backend as nb
from sim_network.connectivity import delay_steps

needs_nest = pytest.mark.skipif(
    not nb.nest_available(), reason=f"NEST is not installed: {nb.INSTALL_HINT}"
)


#: A small culture of NEST's own izhikevich: no adaptation, no slow current (issue 21's
#: additions, which take NeuVision's NEST module).
SMALL = NetworkConfig(
    layout=LayoutConfig(rows=8, cols=8),
    adaptation=AdaptationConfig(increment_exc_mv_per_ms=0.0),
    slow_current=SlowCurrentConfig(share=0.0),
)
#: Uncoupled neurons, driven above threshold by their noise: each one's spikes show its drive.
UNCOUPLED = dataclasses.replace(
    SMALL,
    connectivity=ConnectivityConfig(p_c_max=0.0),
    noise=NoiseConfig(mean=5.0, sd=2.5, inhibitory_mean=None),
)


def same(a: Spikes, b: Spikes) -> bool:
    return np.array_equal(a.channel, b.channel) and np.array_equal(a.t_ms, b.t_ms)


def first_spikes(spikes: Spikes, n: int) -> np.ndarray:
    first = np.full(n, np.nan)
    for i in range(n):
        t = spikes.t_ms[spikes.channel == i]
        if t.size:
            first[i] = t[0]
    return first


# ------------------------------------------------------------------ refusals (no NEST needed)


def test_the_culture_before_issue_21_is_expressible():
    assert nb.refusals(load_config("configs/culture_1024_local.toml")) == []


@pytest.mark.parametrize(
    "cfg, named",
    [
        (dataclasses.replace(SMALL, neurons=NeuronConfig(model="hh")), "neurons.model = 'hh'"),
        (dataclasses.replace(SMALL, neurons=NeuronConfig(model="lif")), "neurons.model = 'lif'"),
        (dataclasses.replace(SMALL, stdp=StdpConfig(enabled=True)), "stdp.enabled with depression"),
        (
            dataclasses.replace(
                SMALL,
                depression=DepressionConfig(u=0.0),
                stdp=StdpConfig(enabled=True, a_plus_mv=0.0),
            ),
            "stdp.a_plus_mv = 0",
        ),
    ],
)
def test_what_nest_cannot_express_is_refused_by_name(cfg, named):
    (found,) = nb.refusals(cfg)
    assert found.startswith(named)
    with pytest.raises(ConfigError, match="culture.params." + named.split(" ")[0]):
        nb.check_expressible(cfg, "culture.params.")


def test_the_default_culture_is_expressible_with_neuvision_s_nest_module():
    cfg = load_config("configs/culture_1024.toml")
    assert nb.refusals(cfg) == [] and nb.needs_module(cfg)
    assert not nb.needs_module(load_config("configs/culture_1024_local.toml"))


def test_every_section_of_a_culture_file_is_known_to_the_nest_backend():
    # a new section must be built in NEST or refused by name (refusals), never ignored
    assert {f.name for f in dataclasses.fields(NetworkConfig)} <= set(nb.KNOWN_SECTIONS)


def test_nest_delays_land_jumps_when_sim_network_lands_them():
    assert nb.nest_delay_steps(np.array([1, 2, 20, 31])).tolist() == [1, 1, 19, 30]


def test_a_nest_without_mpi_started_as_several_ranks_refuses(monkeypatch):
    monkeypatch.setenv("OMPI_COMM_WORLD_SIZE", "4")
    with pytest.raises(nb.MpiMismatch, match="built without MPI"):
        nb.mpi_world(SimpleNamespace(num_processes=1))
    monkeypatch.delenv("OMPI_COMM_WORLD_SIZE")
    assert nb.mpi_world(SimpleNamespace(num_processes=1)) == (None, 0, 1)


@pytest.mark.slow  # seconds of both simulators' noise
def test_the_noise_replayed_is_the_culture_s_own():
    # the windows _NoiseReplay draws are the currents sim_network draws, window by window
    net = Network(SMALL, seed=3)
    state = net.noise_state.copy()
    mean = np.where(net.layout.cell_type == 0, *[SMALL.noise.of_population(f)[0] for f in (0, 1)])
    sd = np.full(net.n_neurons, SMALL.noise.sd)
    drawn = np.empty((5, net.n_neurons), dtype=np.float32)
    nb._draw_windows(state, mean.astype(np.float32), sd.astype(np.float32), drawn)
    for w in range(5):
        net.run(SMALL.noise.interval_ms)
        assert np.array_equal(net.noise_cur, drawn[w])


# ------------------------------------------------------------------ built and run in NEST


@needs_nest
def test_the_network_is_the_sampler_s_neurons_and_synapses():
    cfg = dataclasses.replace(SMALL, layout=LayoutConfig(rows=10, cols=10))
    ref = Network(cfg, seed=5)
    net = nb.NestNetwork(cfg, seed=5)
    assert net.n_connections == ref.synapses.n_synapses > 500
    assert np.array_equal(net.layout.cell_type, ref.layout.cell_type)
    assert np.allclose(net.weights(), ref.synapses.weight_mv)  # the delivered jump, mV

    def read():
        conns = net.nest.GetConnections(net._nodes, net._nodes).get(["source", "target", "delay"])
        nodes = net._nodes.get(["a", "b", "c", "d"])
        return conns, nodes

    conns, nodes = nb.nest_thread().call(read)
    src = np.asarray(conns["source"]) - net._first_id
    tgt = np.asarray(conns["target"]) - net._first_id
    syn = ref.synapses
    order = np.lexsort((syn.post, syn.pre()))
    got = np.lexsort((tgt, src))
    assert np.array_equal(src[got], syn.pre()[order]) and np.array_equal(tgt[got], syn.post[order])
    want = nb.nest_delay_steps(delay_steps(syn.delay_ms, cfg.dt_ms))[order] * cfg.dt_ms
    assert np.allclose(np.asarray(conns["delay"])[got], want)
    for row, key in enumerate("abcd"):
        assert np.allclose(nodes[key], ref.params[row])


@needs_nest
def test_its_noise_drives_each_neuron_as_in_sim_network():
    # the same currents in the same windows, from step 0 on: each uncoupled neuron first
    # fires when it does in sim_network (the integrators differ only slightly, see docs/nest.md)
    sim = first_spikes(Network(UNCOUPLED, seed=2).run(100.0), 64)
    nest = first_spikes(nb.NestNetwork(UNCOUPLED, seed=2).run(100.0), 64)
    assert np.isfinite(sim).all() and np.isfinite(nest).all()
    assert np.median(np.abs(nest - sim)) <= 0.2
    gauss = first_spikes(nb.NestNetwork(UNCOUPLED, seed=2, noise_source="nest").run(100.0), 64)
    assert np.median(np.abs(gauss - sim)) > 0.5  # NEST's own noise is another drive


@needs_nest
def test_a_pulse_acts_on_the_steps_it_acts_on_in_sim_network():
    quiet = dataclasses.replace(
        UNCOUPLED, noise=NoiseConfig(mean=0.0, sd=0.0, inhibitory_mean=None)
    )
    pulse = Pulses(
        np.array([5, 9]), np.array([100.0, 60.0]), np.array([10.0, 20.0]), np.array([3.0, 7.3])
    )
    sim = Network(quiet, seed=1).run(40.0, pulse)
    net = nb.NestNetwork(quiet, seed=1)
    nest = net.run(40.0, pulse)
    assert set(nest.channel.tolist()) == set(sim.channel.tolist()) == {5, 9}
    for i in (5, 9):
        assert np.abs(nest.t_ms[nest.channel == i][0] - sim.t_ms[sim.channel == i][0]) <= 0.1
    # nothing left on once the pulses are over
    assert not net._i_e.any() and len(net.run(50.0)) == 0


@needs_nest
def test_runs_in_chunks_with_pulses_carried_over_equal_one_run():
    # short calls, then a long one (its noise loaded while earlier windows are still due),
    # then short ones again: the same spikes as one call
    sizes = [10.0] * 25 + [1300.0] + [10.0] * 10 + [0.0, 0.5, 89.5]
    pulse = Pulses.single([17, 40], 80.0, 25.0, onset_ms=4.0)
    net = nb.NestNetwork(SMALL, seed=4)
    whole = net.run(sum(sizes), pulse)
    net.set_state({"step": np.array(0)})  # back to the network as built
    parts = [net.run(size, pulse if i == 0 else None) for i, size in enumerate(sizes)]
    assert len(whole) > 200 and same(whole, Spikes.concat(parts))
    assert net.t_ms == pytest.approx(sum(sizes))


@needs_nest
@pytest.mark.slow  # seconds of both simulators
def test_uncoupled_neurons_fire_as_in_sim_network_for_seconds():
    # the noise stays the culture's over many loads of the generators
    cfg = dataclasses.replace(
        load_config("configs/culture_1024_local.toml"), connectivity=ConnectivityConfig(p_c_max=0.0)
    )
    sim, net = Network(cfg, seed=1), nb.NestNetwork(cfg, seed=1)
    for size in (1000.0, *[10.0] * 100, 1000.0):
        a, b = sim.run(size), net.run(size)
    counts = [np.bincount(s.channel, minlength=cfg.n_neurons) for s in (a, b)]
    assert np.mean(counts[0] == counts[1]) > 0.85  # the integrators differ slightly
    assert abs(len(b) / len(a) - 1) < 0.05


@needs_nest
def test_it_returns_to_the_network_as_built_and_refuses_other_states():
    net = nb.NestNetwork(SMALL, seed=6)
    start = net.get_state()
    first = net.run(150.0)
    with pytest.raises(NotImplementedError):
        net.get_state()
    net.reset(background=True)  # as the endpoint does when a run ends
    again = net.run(150.0)  # waits for the rebuild
    net.set_state(start)
    assert same(first, again) and same(first, net.run(150.0))
    with pytest.raises(NotImplementedError):
        net.set_state({"step": np.array(3)})


@needs_nest
def test_nest_threads_change_nothing_with_the_culture_s_noise():
    one = nb.NestNetwork(SMALL, seed=2, threads=1).run(500.0)
    two = nb.NestNetwork(SMALL, seed=2, threads=2).run(500.0)
    assert len(one) > 50 and same(one, two)


@needs_nest
def test_it_runs_from_any_thread_and_one_nest_network_lives_per_process():
    net = nb.NestNetwork(SMALL, seed=1)
    out = []
    t = threading.Thread(target=lambda: out.append(net.run(50.0)))  # as a Zenoh callback
    t.start()
    t.join()
    assert out and net.t_ms == 50.0
    nb.NestNetwork(SMALL, seed=2)
    with pytest.raises(nb.NestRetired):
        net.run(10.0)


@needs_nest
def test_virtual_mea_channels_are_sim_network_s():
    cfg = dataclasses.replace(
        load_config("configs/culture_1024_local.toml"), channels="mea", layout=LayoutConfig(16, 16)
    )
    ref = Network(cfg, seed=1)
    net = nb.NestNetwork(cfg, seed=1)
    assert net.channels.kind == "electrode"
    assert np.array_equal(net.channels.channel, ref.channels.channel)
    assert np.array_equal(net.channels.x_um, ref.channels.x_um)
    spikes = net.run(300.0, Pulses.single([0], 100.0, 10.0))
    assert spikes.channel.max() < ref.channels.channel.size
    assert len(spikes) >= 1


@needs_nest
def test_stdp_changes_excitatory_weights_within_their_bounds():
    cfg = dataclasses.replace(
        SMALL,
        depression=DepressionConfig(u=0.0),
        stdp=StdpConfig(enabled=True, a_plus_mv=0.5, a_minus_mv=0.55, w_max_mv=10.0),
        noise=NoiseConfig(mean=3.0, sd=3.0),
    )
    net = nb.NestNetwork(cfg, seed=1)
    before = net.weights()
    net.run(2000.0)
    after = net.weights()
    exc = net.layout.cell_type[net.synapses.pre()] == 0
    assert not np.allclose(after[exc], np.clip(before[exc], 0, 10))
    assert after[exc].min() >= 0 and after[exc].max() <= 10.0 + 1e-9
    assert np.array_equal(after[~exc], before[~exc])


class FakeComm:
    """mpi4py's COMM_WORLD as rank 0 or a follower sees it, in one process: what is sent is
    kept; a follower receives a script."""

    def __init__(self, script=()):
        self.sent, self.script = [], list(script)

    def bcast(self, obj, root=0):
        if obj is None:
            return self.script.pop(0)
        self.sent.append(obj)
        return obj

    def gather(self, obj, root=0):
        return [obj, (np.zeros(0, np.int64), np.zeros(0, np.int64))]  # a second rank: none


@needs_nest
def test_rank_0_sends_each_call_to_the_other_ranks_before_making_it():
    net = nb.NestNetwork(SMALL, seed=1)
    alone = net.run(100.0)
    net.set_state(net_state := {"step": np.array(0)})
    net.comm, net.rank = FakeComm(), 0
    pulses = Pulses.single([3], 100.0, 10.0)
    together = net.run(100.0, pulses)  # the spikes of rank 0 and of an empty rank 1
    net.potentials()
    net.set_state(net_state)
    net.close()
    names = [name for name, _ in net.comm.sent]
    assert names == ["_run", "_potentials", "_rebuild_if_run", "_stop"]
    (n_steps, added) = net.comm.sent[0][1]
    assert n_steps == 1000 and added.neuron.tolist() == [3]
    assert 3 in together.channel and len(together) >= len(alone) > 0


@needs_nest
def test_a_follower_does_what_rank_0_sends_until_it_stops():
    net = nb.NestNetwork(SMALL, seed=1)
    net.comm = FakeComm([("_run", (500, None)), ("_potentials", ()), ("_stop", ())])
    net.rank = 1
    net.follow()
    assert net.t_ms == pytest.approx(50.0) and net.comm.script == []


# ------------------------------------------------------------------ NeuVision's NEST module


@pytest.mark.slow  # NeuVision's NEST module, built on first use
def test_the_module_s_neuron_is_nest_s_izhikevich_when_its_currents_are_off(module_built):
    def spikes(model: str):
        def simulate():
            nest = nb.import_nest()
            nest.ResetKernel()
            nest_module.install(nest, module_built)
            nest.set(resolution=0.1, rng_seed=3)
            params = {"V_th": 30.0, "V_min": -100.0, "I_e": 5.0}
            if model == "izhikevich":
                params["consistent_integration"] = True
            nodes = nest.Create(model, 40, params=params)
            drive = nest.Create("poisson_generator", params={"rate": 2000.0})
            nest.Connect(drive, nodes, syn_spec={"weight": 2.0, "delay": 1.0})
            rule = {"rule": "fixed_indegree", "indegree": 5}
            nest.Connect(nodes, nodes, rule, {"weight": 3.0, "delay": 1.5})
            recorder = nest.Create("spike_recorder")
            nest.Connect(nodes, recorder)
            nest.Simulate(1000.0)
            events = recorder.get("events")
            return np.asarray(events["senders"]), np.asarray(events["times"])

        return nb.nest_thread().call(simulate)

    ref, ours = spikes("izhikevich"), spikes(nest_module.MODEL)
    assert len(ref[0]) > 500
    assert np.array_equal(ref[0], ours[0]) and np.array_equal(ref[1], ours[1])


#: A small coupled culture without noise: what moves it is a pulse and what follows from it.
QUIET = dataclasses.replace(SMALL, noise=NoiseConfig(mean=0.0, sd=0.0, inhibitory_mean=None))


def regular_spiking_cell(cfg) -> int:
    """The first excitatory cell of the culture that adapts (not chattering-like)."""
    net = Network(dataclasses.replace(cfg, adaptation=AdaptationConfig()), seed=1)
    return int(np.flatnonzero((net.layout.cell_type == 0) & ~net.chattering_like)[0])


def potentials_every_step(net, pulse: Pulses, n_steps: int) -> tuple[np.ndarray, Spikes]:
    """The culture's membrane potentials after each 0.1 ms step, and its spikes."""
    spikes, potentials = [], []
    for k in range(n_steps):
        spikes.append(net.run(0.1, pulse if k == 0 else None))
        potentials.append(net.potentials())
    return np.array(potentials), Spikes.concat(spikes)


@pytest.mark.slow  # NEST module
def test_the_adaptation_current_spaces_a_driven_cell_s_spikes_as_in_sim_network(module_built):
    # 30 ms of 100 units into one regular-spiking cell of a quiet culture: its spikes
    cfg = dataclasses.replace(QUIET, adaptation=AdaptationConfig())
    cell = regular_spiking_cell(cfg)
    pulse = Pulses.single([cell], 100.0, 30.0)

    def spikes_of_cell(net):
        out = net.run(40.0, pulse)
        return out.t_ms[out.channel == cell]

    sim, nest = spikes_of_cell(Network(cfg, seed=1)), spikes_of_cell(nb.NestNetwork(cfg, seed=1))
    without = spikes_of_cell(Network(QUIET, seed=1))
    assert len(without) > 2 * len(sim) >= 6  # the adaptation matters here
    assert len(nest) == len(sim) and np.abs(nest - sim).max() <= 1.0


@pytest.mark.slow  # NEST module
def test_the_slow_current_follows_a_jump_as_in_sim_network(module_built):
    # one spike of one cell in a quiet culture; the potentials of all cells for 30 ms after:
    # what the slow current changes in them is what it changes in sim_network (the two
    # integrators differ slightly with or without it: docs/nest.md)
    cfg = dataclasses.replace(QUIET, slow_current=SlowCurrentConfig(share=0.8))
    pulse = Pulses.single([regular_spiking_cell(cfg)], 100.0, 1.0)
    sim, sim_spikes = potentials_every_step(Network(cfg, seed=1), pulse, 300)
    nest, nest_spikes = potentials_every_step(nb.NestNetwork(cfg, seed=1), pulse, 300)
    sim_off, _ = potentials_every_step(Network(QUIET, seed=1), pulse, 300)
    nest_off, _ = potentials_every_step(nb.NestNetwork(QUIET, seed=1), pulse, 300)
    assert same(sim_spikes, nest_spikes) and len(sim_spikes) >= 1
    in_sim, in_nest = sim - sim_off, nest - nest_off
    reached = np.abs(in_sim).max(axis=0) > 0.5  # the cells its jumps reach (mV)
    assert reached.sum() >= 3
    difference = np.abs(in_nest - in_sim)[:, reached].mean()
    assert difference < 0.05 * np.abs(in_sim)[:, reached].mean()


@pytest.mark.slow  # NEST module
def test_the_default_culture_builds_in_nest_with_each_neuron_s_increment(module_built):
    cfg = dataclasses.replace(load_config("configs/culture_1024.toml"), layout=LayoutConfig(8, 8))
    ref = Network(cfg, seed=2)
    net = nb.NestNetwork(cfg, seed=2)
    keys = ["model", "adapt_increment", "tau_adapt", "slow_share", "tau_slow"]
    got = nb.nest_thread().call(lambda: net._nodes.get(keys))
    assert set(got["model"]) == {nest_module.MODEL}
    assert np.allclose(got["adapt_increment"], ref.adaptation_increment)
    assert (
        ref.chattering_like.any()
        and not np.asarray(got["adapt_increment"])[ref.chattering_like].any()
    )
    assert set(got["tau_adapt"]) == {25.0} and set(got["tau_slow"]) == {40.0}
    assert set(got["slow_share"]) == {0.8}
    assert len(net.run(200.0)) > 0


@pytest.mark.slow  # NEST module
def test_the_module_s_neurons_draw_the_culture_s_noise_value_for_value(module_built):
    # no current generator per neuron: each neuron's own generator, seeded and drawn as
    # sim_network seeds and draws it, window after window
    cfg = dataclasses.replace(load_config("configs/culture_1024.toml"), layout=LayoutConfig(8, 8))
    ref, net = Network(cfg, seed=3), nb.NestNetwork(cfg, seed=3)
    for _ in range(5):
        ref.run(cfg.noise.interval_ms)
        net.run(cfg.noise.interval_ms)
        drawn = nb.nest_thread().call(lambda: net._nodes.get("I_noise"))
        assert np.array_equal(np.asarray(drawn, dtype=np.float32), ref.noise_cur)


@pytest.mark.slow  # NEST module
def test_the_module_s_noise_changes_nothing_with_nest_s_threads(module_built):
    cfg = dataclasses.replace(load_config("configs/culture_1024.toml"), layout=LayoutConfig(8, 8))
    one = nb.NestNetwork(cfg, seed=2, threads=1).run(500.0)
    two = nb.NestNetwork(cfg, seed=2, threads=2).run(500.0)
    assert len(one) > 50 and same(one, two)
