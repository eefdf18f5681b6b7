"""Network runs: determinism, chunking, pulses, noise, state, channels and the virtual MEA."""

import dataclasses
import json

import numpy as np
import pytest

from sim_network import (
    AdaptationConfig,
    ConnectivityConfig,
    LayoutConfig,
    Network,
    NetworkConfig,
    NoiseConfig,
    PeriodicStimulus,
    PulseError,
    Pulses,
    SlowCurrentConfig,
    Spikes,
    StdpConfig,
    load_config,
)
from sim_network.connectivity import build_synapses
from sim_network.kernels import fill_noise, seed_noise_state
from sim_network.layout import build_layout

SMALL = NetworkConfig(  # the paper's model: no adaptation, no slow current
    layout=LayoutConfig(rows=12, cols=12),
    connectivity=ConnectivityConfig(weight_exc_mv=(0.0, 12.0)),
    noise=NoiseConfig(sd=4.5),
    adaptation=AdaptationConfig(increment_exc_mv_per_ms=0.0),
    slow_current=SlowCurrentConfig(share=0.0),
)


def same(a: Spikes, b: Spikes) -> bool:
    return np.array_equal(a.channel, b.channel) and np.array_equal(a.t_ms, b.t_ms)


def chunked(net: Network, sizes, pulses_at=None) -> Spikes:
    parts = []
    for i, size in enumerate(sizes):
        parts.append(net.run(size, pulses=(pulses_at or {}).get(i)))
    return Spikes.concat(parts)


def test_same_seed_gives_identical_spikes_and_other_seed_differs():
    a = Network(SMALL, seed=7).run(500.0)
    b = Network(SMALL, seed=7).run(500.0)
    c = Network(SMALL, seed=8).run(500.0)
    assert len(a) > 50
    assert same(a, b)
    assert not same(a, c)


@pytest.mark.parametrize(
    "sizes", [[500.0, 500.0], [0.1] * 7 + [99.3, 400.0, 0.0, 500.0], [10.0] * 100]
)
def test_chunked_runs_equal_one_run(sizes):
    whole = Network(SMALL, seed=2).run(1000.0)
    parts = chunked(Network(SMALL, seed=2), sizes)
    assert same(whole, parts)


def test_chunking_with_pulses_spanning_calls_equals_one_run():
    pulses = Pulses(
        channel=[3, 40, 77, 3],
        amplitude_ua=[100.0, 60.0, 100.0, 20.0],
        width_ms=[10.0, 35.0, 10.0, 300.0],
        onset_ms=[5.0, 95.0, 403.0, 250.0],
    )
    whole = Network(SMALL, seed=4).run(1000.0, pulses=pulses)
    # the same pulses handed over at once to the first of many 10 ms calls (carried over) ...
    parts = chunked(Network(SMALL, seed=4), [10.0] * 100, {0: pulses})
    assert same(whole, parts)
    # ... or each handed to the call in which it starts, with the onset relative to that call
    net = Network(SMALL, seed=4)
    per_call = {}
    for ch, amp, width, onset in zip(*dataclasses.astuple(pulses), strict=True):
        call = int(onset // 10)
        per_call.setdefault(call, []).append((ch, amp, width, onset - 10 * call))
    handed = {k: Pulses(*map(np.array, zip(*v, strict=True))) for k, v in per_call.items()}
    assert same(whole, chunked(net, [10.0] * 100, handed))


def test_stimulation_changes_the_activity():
    quiet = Network(SMALL, seed=1).run(200.0)
    stim = Network(SMALL, seed=1).run(200.0, pulses=Pulses.single([10], 100.0, 10.0, 50.0))
    target = stim.t_ms[(stim.channel == 10) & (stim.t_ms > 50) & (stim.t_ms <= 61)]
    assert target.size >= 2  # a 100 µA, 10 ms pulse makes the target fire
    assert not same(quiet, stim)


def test_periodic_stimulus_delivers_each_pulse_once():
    stim = PeriodicStimulus((5, 6), 100.0, 10.0, 200.0, start_ms=30.0, count=3)
    assert np.allclose(stim.onsets_ms(), [30.0, 230.0, 430.0])
    got = [stim.pulses_between(t0, t0 + 100.0) for t0 in np.arange(0.0, 600.0, 100.0)]
    assert sum(len(p) for p in got) == 6
    assert np.allclose(got[2].onset_ms, [30.0, 30.0]) and list(got[2].channel) == [5, 6]


def test_spikes_are_sorted_absolute_and_in_range():
    net = Network(SMALL, seed=3)
    net.run(300.0)
    sp = net.run(200.0)
    assert np.all(np.diff(sp.t_ms) >= 0)
    assert sp.t_ms.min() > 300.0 and sp.t_ms.max() <= 500.0
    assert sp.channel.dtype == np.uint32 and sp.t_ms.dtype == np.float64
    assert net.t_ms == pytest.approx(500.0)


def test_save_and_load_continue_identically(tmp_path):
    cfg = dataclasses.replace(SMALL, stdp=StdpConfig(enabled=True))
    ref = Network(cfg, seed=9)
    ref.run(300.0, pulses=Pulses.single([1], 80.0, 50.0, 280.0))  # pulse spans the checkpoint
    ref.save(tmp_path / "net.ckpt")
    expected = ref.run(400.0)
    again = Network.load(tmp_path / "net.ckpt")
    assert again.t_ms == pytest.approx(300.0)
    assert same(expected, again.run(400.0))
    assert np.array_equal(ref.potentials(), again.potentials())


def test_checkpoint_of_the_former_noise_generator_is_refused_clearly(tmp_path):
    """Version 1 checkpoints hold xoroshiro128+ noise states (2, n) uint64, a generator this
    version no longer has: loading one says so instead of continuing with another stream."""
    Network(SMALL, seed=4).save(tmp_path / "net.ckpt")
    with np.load(tmp_path / "net.ckpt") as data:
        saved = {k: data[k] for k in data.files}
    meta = json.loads(str(saved["meta"]))
    meta["version"] = 1
    saved["meta"] = np.array(json.dumps(meta))
    saved["noise_state"] = np.ones((2, 144), dtype=np.uint64)
    with open(tmp_path / "v1.ckpt", "wb") as fh:
        np.savez(fh, **saved)
    with pytest.raises(ValueError, match="former noise generator.*config and seed"):
        Network.load(tmp_path / "v1.ckpt")


def test_synapse_rows_are_in_ring_order_and_hold_the_drawn_synapses():
    net = Network(SMALL, seed=3)
    syn = net.synapses
    pre = syn.pre()
    # the kernel needs each row ascending in ring offset: delay step, then post
    key = net._target.astype(np.int64)
    assert np.all((np.diff(key) > 0) | (np.diff(pre) != 0))
    # the same synapses as the builder drew, only reordered within rows
    rng = np.random.default_rng([3, 0x5E7])
    drawn = build_synapses(build_layout(SMALL.layout, rng), SMALL.connectivity, rng)
    assert np.array_equal(drawn.indptr, syn.indptr)
    a = np.lexsort((drawn.post, drawn.pre()))
    b = np.lexsort((syn.post, pre))
    for name in ("post", "weight_mv", "delay_ms", "distance_um"):
        assert np.array_equal(getattr(drawn, name)[a], getattr(syn, name)[b]), name


def test_checkpoint_with_rows_in_another_order_loads_and_continues(tmp_path):
    """A checkpoint whose rows are in another order (as saved before rows were sorted)."""
    cfg = dataclasses.replace(SMALL, stdp=StdpConfig(enabled=True))
    ref = Network(cfg, seed=4)
    ref.run(300.0)
    ref.save(tmp_path / "net.ckpt")
    expected = ref.run(300.0)
    with np.load(tmp_path / "net.ckpt") as data:
        saved = {k: data[k] for k in data.files}
    indptr = saved["syn_indptr"]
    rev = np.concatenate([np.arange(indptr[i + 1] - 1, indptr[i] - 1, -1) for i in range(144)])
    for key in ("syn_post", "syn_weight_mv", "syn_delay_ms", "syn_distance_um", "weight"):
        saved[key] = saved[key][rev]
    with open(tmp_path / "old.ckpt", "wb") as fh:
        np.savez(fh, **saved)
    again = Network.load(tmp_path / "old.ckpt")
    assert same(expected, again.run(300.0))
    assert np.array_equal(ref.weight, again.weight)
    assert np.array_equal(ref.synapses.post, again.synapses.post)


def test_stdp_changes_excitatory_weights_only():
    cfg = dataclasses.replace(SMALL, stdp=StdpConfig(enabled=True, w_max_mv=12.0))
    net = Network(cfg, seed=1)
    w0 = net.weight.copy()
    net.run(1000.0)
    exc = net.layout.cell_type[net.synapses.pre()] == 0
    assert not np.array_equal(net.weight[exc], w0[exc])
    assert np.array_equal(net.weight[~exc], w0[~exc])
    assert net.weight[exc].min() >= 0 and net.weight[exc].max() <= 12.0


def test_adaptation_off_leaves_its_current_at_zero_and_tau_irrelevant():
    a = Network(SMALL, seed=4)
    off = AdaptationConfig(increment_exc_mv_per_ms=0.0, tau_ms=20.0)
    b = Network(dataclasses.replace(SMALL, adaptation=off), seed=4)
    assert same(a.run(500.0), b.run(500.0))
    assert not a.aux[2].any() and not a.adaptation_current().any()


def test_adaptation_current_grows_per_spike_decays_and_lowers_the_rate():
    inc, tau = 3.0, 100.0
    cfg = dataclasses.replace(
        SMALL, adaptation=AdaptationConfig(increment_exc_mv_per_ms=inc, tau_ms=tau)
    )
    free, adapted = Network(SMALL, seed=4), Network(cfg, seed=4)
    exc = adapted.layout.cell_type == 0
    n_free = np.bincount(free.run(2000.0).channel, minlength=free.n_neurons)
    spikes = adapted.run(2000.0)
    n_adapted = np.bincount(spikes.channel, minlength=adapted.n_neurons)
    assert n_adapted[exc].sum() < 0.8 * n_free[exc].sum()
    w = adapted.adaptation_current()
    assert not w[~exc].any() and (w[exc] >= 0).all()
    # w is the sum of the increments of each spike, decayed since: check one neuron exactly
    i = int(np.flatnonzero(exc & (n_adapted > 0))[0])
    t_spikes = spikes.t_ms[spikes.channel == i]
    steps_since = np.rint((adapted.t_ms - t_spikes) / adapted.cfg.dt_ms)
    expected = inc * np.sum(np.exp(-adapted.cfg.dt_ms / tau) ** (steps_since - 1))
    assert w[i] == pytest.approx(expected, rel=3e-3)  # float32, decayed in ~20k steps


def test_slow_current_takes_a_share_of_each_jump_and_decays():
    share, tau = 0.8, 40.0
    cfg = dataclasses.replace(SMALL, slow_current=SlowCurrentConfig(share=share, tau_ms=tau))
    net = Network(cfg, seed=3)
    net.run(200.0)
    # 5 mV more due next step at neuron 0: its slow current grows by share / tau x the jump
    slot = net.step % net.ring.shape[0]
    net.ring[slot, 0] += 5.0
    jump, before = float(net.ring[slot, 0]), float(net.aux[3, 0])
    net.run(net.cfg.dt_ms)
    arrived = float(net.aux[3, 0]) - before * np.exp(-net.cfg.dt_ms / tau)
    assert arrived == pytest.approx(share * jump / tau, rel=1e-4, abs=1e-6)
    assert not Network(SMALL, seed=3).aux[3].any()


def test_slow_current_lengthens_the_response_to_a_pulse():
    def late_spikes(cfg):
        net = Network(cfg, seed=5)
        net.run(500.0)
        sp = net.run(100.0, pulses=Pulses.single(list(range(40)), 100.0, 10.0))
        return int(np.sum(sp.t_ms > net.t_ms - 100.0 + 30.0))

    slow = dataclasses.replace(SMALL, slow_current=SlowCurrentConfig(share=0.8, tau_ms=40.0))
    assert late_spikes(slow) > late_spikes(SMALL)


def test_chattering_like_cells_are_exempt_from_adaptation():
    cfg = load_config("configs/culture_1024.toml")
    ada = cfg.adaptation
    assert ada.increment_exc_mv_per_ms > 0 and ada.exempt_from_reset_mv is not None
    net = Network(cfg, seed=1)
    exc = net.layout.cell_type == 0
    exempt = exc & (net.params[2] >= ada.exempt_from_reset_mv)
    assert 0.1 < exempt.sum() / exc.sum() < 0.5  # the chattering end of the RS -> CH spread
    assert (net.chattering_like == exempt).all()
    assert not net._adapt_inc[exempt].any() and not net._adapt_inc[~exc].any()
    assert (net._adapt_inc[exc & ~exempt] == ada.increment_exc_mv_per_ms).all()
    spikes = net.run(1000.0)
    fired = np.bincount(spikes.channel, minlength=net.n_neurons) > 0
    w = net.adaptation_current()
    assert not w[exempt].any() and w[exc & ~exempt & fired].all()


@pytest.mark.parametrize("sizes", [[0.1] * 7 + [99.3, 400.0, 0.0, 500.0], [10.0] * 100])
def test_chunked_runs_with_adaptation_equal_one_run(sizes):
    # the amplitudes are renormalised every 1024 steps (102.4 ms): chunks straddle that
    cfg = dataclasses.replace(SMALL, adaptation=AdaptationConfig(increment_exc_mv_per_ms=2.0))
    whole = Network(cfg, seed=2)
    assert whole._adapt_g.size - 1 == 1024
    expected = whole.run(1000.0)
    parts = Network(cfg, seed=2)
    assert same(expected, chunked(parts, sizes))
    assert np.array_equal(whole.adaptation_current(), parts.adaptation_current())


def test_checkpoint_with_adaptation_continues_identically(tmp_path):
    cfg = dataclasses.replace(SMALL, adaptation=AdaptationConfig(increment_exc_mv_per_ms=2.0))
    ref = Network(cfg, seed=3)
    ref.run(300.0)
    ref.save(tmp_path / "net.ckpt")
    expected = ref.run(300.0)
    again = Network.load(tmp_path / "net.ckpt")
    assert same(expected, again.run(300.0))


def test_potentials_snapshot():
    net = Network(SMALL, seed=1)
    net.run(50.0)
    v = net.potentials()
    assert v.dtype == np.float32 and v.shape == (144,)
    assert np.all((v >= -100.0) & (v <= 30.0))


def seeded_noise_state(n: int, seed: int = 12345) -> np.ndarray:
    state = np.zeros((4, n), dtype=np.uint32)  # xoshiro128++: four 32-bit words per neuron
    seed_noise_state(np.uint64(seed), state)
    return state


def test_noise_has_the_configured_mean_and_sd():
    state = seeded_noise_state(200_000)
    cur = np.empty(200_000, dtype=np.float32)
    mean, sd = np.full(200_000, 2.0, np.float32), np.full(200_000, 5.0, np.float32)
    fill_noise(cur, state, mean, sd)
    assert cur.mean() == pytest.approx(2.0, abs=0.05)
    assert cur.std() == pytest.approx(5.0, rel=0.01)
    z = (cur.astype(np.float64) - 2.0) / 5.0
    assert np.mean(z**4) == pytest.approx(2.7, abs=0.05)  # Irwin-Hall(4): bell-shaped
    assert np.abs(z).max() <= np.sqrt(12.0)
    other = np.empty(200_000, dtype=np.float32)
    fill_noise(other, state, mean, sd)
    assert abs(np.corrcoef(cur, other)[0, 1]) < 0.01  # successive windows are independent
    assert abs(np.corrcoef(cur[1:], cur[:-1])[0, 1]) < 0.01  # and so are neighbours


def xoshiro128pp_reference(s: list[int]) -> int:
    """xoshiro128++ next() (Blackman & Vigna, prng.di.unimi.it), transcribed from the C."""

    def rotl(x: int, k: int) -> int:
        return ((x << k) | (x >> (32 - k))) & 0xFFFFFFFF

    result = (rotl((s[0] + s[3]) & 0xFFFFFFFF, 7) + s[0]) & 0xFFFFFFFF
    t = (s[1] << 9) & 0xFFFFFFFF
    s[2] ^= s[0]
    s[3] ^= s[1]
    s[1] ^= s[2]
    s[0] ^= s[3]
    s[2] ^= t
    s[3] = rotl(s[3], 11)
    return result


def test_noise_generator_is_xoshiro128pp_and_its_bytes_make_the_variate():
    n = 5
    state = seeded_noise_state(n, 2024)
    ref = [[int(w) for w in state[:, j]] for j in range(n)]
    cur = np.empty(n, dtype=np.float32)
    for _ in range(50):
        fill_noise(cur, state, np.zeros(n, np.float32), np.ones(n, np.float32))
        for j in range(n):
            r = xoshiro128pp_reference(ref[j])
            total = sum((r >> (8 * b)) & 0xFF for b in range(4))
            z = ((total + 2) / 256 - 2) * np.sqrt(3.0) / np.sqrt(1 - 2.0**-16)
            assert cur[j] == pytest.approx(z, abs=1e-5)
            assert [int(w) for w in state[:, j]] == ref[j]


def test_noise_variate_is_exactly_standardised_irwin_hall():
    """Each draw's four bytes are uniforms on 256 centred cells: z takes 1021 values whose
    exact distribution (the 4-fold convolution) has mean 0 and s.d. 1; the draws follow it."""
    n_draws = 400_000
    cur = np.empty(n_draws, dtype=np.float32)
    fill_noise(
        cur,
        seeded_noise_state(n_draws, 3),
        np.zeros(n_draws, np.float32),
        np.ones(n_draws, np.float32),
    )
    one = np.ones(256)
    counts = np.convolve(np.convolve(one, one), np.convolve(one, one))  # P(byte sum = s) * 2^32
    p = counts / counts.sum()
    s = np.arange(1021)
    z_exact = (s * np.sqrt(3.0) / 256 + (2 / 256 - 2) * np.sqrt(3.0)) / np.sqrt(1 - 2.0**-16)
    assert np.sum(p * z_exact) == pytest.approx(0.0, abs=1e-12)
    assert np.sum(p * z_exact**2) == pytest.approx(1.0, abs=1e-12)
    # every value drawn is one of the 1021 levels, and their frequencies match p (chi-square)
    level = np.rint((cur.astype(np.float64) - z_exact[0]) / (z_exact[1] - z_exact[0])).astype(int)
    assert np.allclose(z_exact[level], cur, atol=1e-5)
    observed = np.bincount(level, minlength=1021)
    # pool the sparse tails into the bins next to them (expected count >= 20)
    exp = p * n_draws
    keep = exp >= 20
    lo, hi = np.argmax(keep), len(keep) - np.argmax(keep[::-1]) - 1
    obs_b = observed[lo : hi + 1].astype(float)
    exp_b = exp[lo : hi + 1].copy()
    obs_b[0] += observed[:lo].sum()
    exp_b[0] += exp[:lo].sum()
    obs_b[-1] += observed[hi + 1 :].sum()
    exp_b[-1] += exp[hi + 1 :].sum()
    chi2 = np.sum((obs_b - exp_b) ** 2 / exp_b)
    dof = len(obs_b) - 1
    assert chi2 < dof + 5 * np.sqrt(2 * dof)


def test_noise_is_independent_across_neurons_and_windows():
    """64 neurons over 20,000 windows: no pair of neurons, and no neuron with itself one to
    three windows later, is correlated beyond sampling noise (|r| < 5/sqrt(windows))."""
    n, windows = 64, 20_000
    state = seeded_noise_state(n, 99)
    mean, sd = np.zeros(n, np.float32), np.ones(n, np.float32)
    draws = np.empty((windows, n), dtype=np.float32)
    for w in range(windows):
        fill_noise(draws[w], state, mean, sd)
    limit = 5.0 / np.sqrt(windows)
    r = np.corrcoef(draws.T)
    assert np.abs(r[~np.eye(n, dtype=bool)]).max() < limit
    for lag in (1, 2, 3):
        a, b = draws[:-lag] - draws.mean(0), draws[lag:] - draws.mean(0)
        r_lag = (a * b).mean(0) / draws.std(0) ** 2
        assert np.abs(r_lag).max() < limit
    assert np.abs(draws.mean(0)).max() < limit  # every neuron's own mean and s.d. are right
    assert np.abs(draws.std(0) - 1.0).max() < 5.0 / np.sqrt(2 * windows)


def test_izhikevich_update_draws_the_same_noise_as_fill_noise():
    """The Izhikevich kernel draws its noise fused into its update pass; it must give the
    stream of the standalone `fill_noise` (used by the other models), at any dt."""
    for dt in (0.1, 1.0):
        net = Network(dataclasses.replace(SMALL, dt_ms=dt), seed=6)
        state = net.noise_state.copy()
        cur = np.empty_like(net.noise_cur)
        for _ in range(3):
            net.run(1.0)  # one noise window
            fill_noise(cur, state, net._noise_mean, net._noise_sd)
            assert np.array_equal(net.noise_cur, cur)
            assert np.array_equal(net.noise_state, state)


def test_inhibitory_noise_can_differ():
    cfg = dataclasses.replace(SMALL, noise=NoiseConfig(mean=0.0, sd=1.0, inhibitory_mean=5.0))
    net = Network(cfg, seed=2)
    net.run(1.0)
    inh = net.layout.cell_type == 1
    assert net.noise_cur[inh].mean() > 4.0 > 1.0 > abs(net.noise_cur[~inh].mean())


@pytest.mark.parametrize("coarse_dt", [0.5, 1.0])
def test_noise_current_does_not_depend_on_dt(coarse_dt):
    fine = Network(dataclasses.replace(SMALL, dt_ms=0.1), seed=5)
    coarse = Network(dataclasses.replace(SMALL, dt_ms=coarse_dt), seed=5)
    for net in (fine, coarse):
        net.run(8.0)
    assert np.array_equal(fine.noise_cur, coarse.noise_cur)


def test_bad_run_arguments_are_rejected():
    net = Network(SMALL, seed=1)
    with pytest.raises(ValueError, match="multiple of dt_ms"):
        net.run(0.25)
    with pytest.raises(ValueError, match="duration_ms"):
        net.run(-1.0)
    with pytest.raises(PulseError, match="out of range"):
        net.run(10.0, pulses=Pulses.single([144], 10.0, 1.0))
    with pytest.raises(PulseError, match="width_ms"):
        Pulses([1], [1.0], [-1.0], [0.0])
    with pytest.raises(PulseError, match="length"):
        Pulses([1, 2], [1.0], [1.0], [0.0])
    with pytest.raises(PulseError, match="finite"):
        Pulses([1], [np.nan], [1.0], [0.0])


@pytest.mark.parametrize(
    "field, value, error",
    [
        ("amplitude_ua", np.nan, "amplitude_ua must be finite"),
        ("amplitude_ua", -np.inf, "amplitude_ua must be finite"),
        ("width_ms", -1.0, "width_ms must be >= 0"),
        ("width_ms", np.inf, "width_ms must be finite"),
        ("onset_ms", -0.5, "onset_ms must be >= 0"),
        ("onset_ms", np.nan, "onset_ms must be finite"),
    ],
)
def test_pulses_in_their_own_dtypes_are_checked_as_closely_as_any(field, value, error):
    # A hub's Stimulation hands over uint32/float32 arrays, which take a quicker path.
    arrays = {
        "channel": np.array([3, 4], np.uint32),
        "amplitude_ua": np.array([50.0, 60.0], np.float32),
        "width_ms": np.array([10.0, 10.0], np.float32),
        "onset_ms": np.array([0.0, 2.0], np.float32),
    }
    assert len(Pulses(**arrays)) == 2
    arrays[field] = arrays[field].copy()
    arrays[field][1] = value
    with pytest.raises(PulseError, match=error):
        Pulses(**arrays)


def test_neuron_channels_describe_the_neurons():
    net = Network(SMALL, seed=1)
    ch = net.channels
    assert ch.kind == "neuron" and len(ch) == 144
    assert np.array_equal(ch.cell_type, net.layout.cell_type)
    assert ch.x_um.dtype == np.float32


def test_virtual_mea_has_sixty_electrodes_and_records_nearby_neurons():
    cfg = dataclasses.replace(load_config("configs/culture_1024.toml"), channels="mea")
    net = Network(cfg, seed=1)
    ch = net.channels
    assert ch.kind == "electrode" and len(ch) == 60 and ch.cell_type is None
    pitch = np.diff(np.unique(ch.x_um))
    assert np.allclose(pitch, 200.0)
    assert np.isclose(ch.x_um.mean(), net.layout.width_um / 2)
    spikes = net.run(500.0)
    neurons = net.neuron_spikes
    assert len(spikes) > 0
    # every electrode spike has a neuron spike at that time within the recording radius
    for e, t in zip(spikes.channel[:200], spikes.t_ms[:200], strict=True):
        at = neurons.channel[neurons.t_ms == t]
        d = np.hypot(net.layout.x_um[at] - ch.x_um[e], net.layout.y_um[at] - ch.y_um[e])
        assert d.min() <= cfg.mea.record_radius_um


def test_mea_pulse_stimulates_neurons_near_the_electrode():
    cfg = dataclasses.replace(
        load_config("configs/culture_1024.toml"),
        channels="mea",
        noise=NoiseConfig(sd=0.0),
        connectivity=ConnectivityConfig(p_c_max=0.0),  # only the direct effect of the pulse
    )
    net = Network(cfg, seed=1)
    net.run(10.0, pulses=Pulses.single([27], 100.0, 10.0))
    fired = np.unique(net.neuron_spikes.channel)
    ch = net.channels
    d = np.hypot(net.layout.x_um[fired] - ch.x_um[27], net.layout.y_um[fired] - ch.y_um[27])
    assert fired.size >= 1 and d.max() <= cfg.mea.stim_radius_um


def test_pulse_into_one_excitatory_neuron_evokes_a_network_response():
    """The paper's protocol (10 ms, 100 µA into one excitatory neuron) on the default culture.

    Compared with the same network continued without the pulse (same state, same noise), the
    stimulated copy fires more spikes in the neurons *other* than the target within 150 ms:
    the pulse recruits the network, and in some trials (when depression has recovered)
    evokes a whole network burst.
    """
    net = Network(load_config("configs/culture_1024.toml"), seed=1)
    net.run(2000.0)
    lay = net.layout
    d = np.hypot(lay.x_um - lay.width_um / 2, lay.y_um - lay.height_um / 2)
    d[lay.cell_type != 0] = np.inf
    target = int(np.argmin(d))
    extra = []
    for _ in range(8):
        state = net.get_state()
        net.run(150.0, pulses=Pulses.single([target], 100.0, 10.0))
        evoked = np.sum(net.neuron_spikes.channel != target)
        net.set_state(state)
        net.run(150.0)
        control = np.sum(net.neuron_spikes.channel != target)
        extra.append(evoked - control)
        net.run(4850.0)  # 0.2 Hz, as in the paper
    assert np.mean(extra) > 100, extra
    assert max(extra) > 500, extra  # at least one large evoked population response


@pytest.mark.parametrize(
    ("model", "noise"),
    [("lif", NoiseConfig(mean=14.0, sd=6.0)), ("hh", NoiseConfig(mean=4.0, sd=6.0))],
)
def test_lif_and_hh_networks_run_deterministically_in_chunks(model, noise):
    from sim_network import NeuronConfig

    cfg = dataclasses.replace(
        SMALL,
        neurons=NeuronConfig(model=model),
        noise=noise,
        connectivity=ConnectivityConfig(weight_exc_mv=(0.0, 2.0), weight_inh_mv=(-2.0, 0.0)),
    )
    whole = Network(cfg, seed=3).run(300.0)
    parts = chunked(Network(cfg, seed=3), [10.0] * 30)
    assert len(whole) > 20
    assert same(whole, parts)


def test_run_rejects_pulses_of_the_wrong_type():
    with pytest.raises(TypeError, match="pulses"):
        Network(SMALL, seed=1).run(10.0, pulses={"channel": [1]})


@pytest.mark.parametrize("dt_ms", [0.1, 1.0])
def test_every_neuron_at_the_peak_is_recorded_whatever_the_network_size(dt_ms):
    # 5 x 7 = 35 neurons: the spike scan takes eight at a time, so the last three are a tail
    cfg = dataclasses.replace(
        SMALL,
        dt_ms=dt_ms,
        layout=LayoutConfig(rows=5, cols=7),
        noise=NoiseConfig(mean=0.0, sd=0.0),
    )
    net = Network(cfg, seed=3)
    spikes = net.run(20.0, pulses=Pulses.single(list(range(35)), 100.0, 20.0))
    assert set(spikes.channel.tolist()) == set(range(35))
    assert np.all(net.potentials() < 30.0)  # every neuron at the peak was reset
