"""The `Network`: builds a culture from a config and seed, runs it, saves and restores it.

Time is counted in whole steps of `dt_ms` from 0; a spike found in step k (time k·dt to
(k+1)·dt) gets the time (k+1)·dt. Pulses are scheduled on absolute steps: a pulse given to
`run()` starts at step round(onset/dt) after the call's first step and lasts round(width/dt)
steps; whatever part of it lies beyond the end of the call (including an onset beyond the
call) is carried over into the following calls. So chunking never changes the result.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from sim_network import kernels, pulse_kernels
from sim_network.config import NetworkConfig, config_from_dict, config_to_dict
from sim_network.connectivity import Synapses, build_synapses, delay_steps
from sim_network.layout import EXCITATORY, Layout, build_layout
from sim_network.mea import Mea, build_mea
from sim_network.neurons import MODEL_IDS, build_params, initial_state, izhikevich_substeps
from sim_network.records import Channels, PulseError, Pulses, Spikes

# 2: noise generators are xoshiro128++ in 32-bit words, noise_state (4, n) uint32 (version 1
# held xoroshiro128+ states (2, n) uint64, a stream this version no longer draws)
_STATE_VERSION = 2
_NEVER = -(2**40)  # "last spike" of a neuron that has not fired yet (depression fully recovered)


def steps_of(duration_ms: float, dt_ms: float) -> int:
    """The number of steps of ``dt_ms`` in ``duration_ms``.

    Parameters
    ----------
    duration_ms, dt_ms : float
        The duration and the step, in ms.

    Raises
    ------
    ValueError
        The duration is not finite and >= 0, or not a whole number of steps.
    """
    duration_ms = float(duration_ms)
    if not math.isfinite(duration_ms) or duration_ms < 0:
        raise ValueError(f"duration_ms must be finite and >= 0, got {duration_ms}")
    n = round(duration_ms / dt_ms)
    if abs(n * dt_ms - duration_ms) > 1e-6 * max(1.0, duration_ms):
        raise ValueError(f"duration_ms must be a multiple of dt_ms={dt_ms}, got {duration_ms}")
    return n


def on_electrodes(mea: Mea, neuron: np.ndarray, t_ms: np.ndarray) -> Spikes:
    """Neurons' spikes as the electrodes that record them see them.

    A spike becomes one spike on each electrode that records its neuron (none when no
    electrode does), in the order of the input.

    Parameters
    ----------
    mea : Mea
        The array; its ``rec_indptr``/``rec_electrode`` CSR say which electrodes record
        which neuron.
    neuron : ndarray of int
        The spiking neuron of each spike.
    t_ms : ndarray of float64
        The time of each spike, in ms (same length as ``neuron``).

    Returns
    -------
    Spikes
        Channels are electrode indices.
    """
    counts = np.diff(mea.rec_indptr)[neuron]
    if counts.sum() == 0:
        return Spikes(np.zeros(0, np.uint32), np.zeros(0, np.float64))
    starts = np.repeat(mea.rec_indptr[neuron] - np.cumsum(counts) + counts, counts)
    idx = starts + np.arange(counts.sum())
    return Spikes(mea.rec_electrode[idx], np.repeat(t_ms, counts))


class Network:
    """A simulated culture; `run()` advances it and returns the spikes in channel space.

    Parameters
    ----------
    cfg : NetworkConfig
        The model; validated on construction.
    seed : int
        Seeds the layout, connectivity, heterogeneity and the noise stream. The same config and
        seed give bit-identical spikes, whether run whole or in chunks of any size.
    """

    def __init__(self, cfg: NetworkConfig, seed: int = 0):
        if not isinstance(cfg, NetworkConfig):
            raise TypeError(f"cfg must be a NetworkConfig, got {type(cfg).__name__}")
        self.cfg = cfg
        self.seed = int(seed)
        rng = np.random.default_rng([self.seed, 0x5E7])
        self.layout: Layout = build_layout(cfg.layout, rng)
        self.synapses: Synapses = build_synapses(self.layout, cfg.connectivity, rng)
        self.params = build_params(cfg, self.layout.cell_type, rng).astype(kernels.STATE_DTYPE)
        self.mea: Mea | None = build_mea(cfg.mea, self.layout) if cfg.channels == "mea" else None
        self._derive()
        self._reset_state()

    # ------------------------------------------------------------------ set-up
    def _derive(self) -> np.ndarray | None:
        """Arrays derived from config and synapses (not state); rebuilt after `load`.

        Sorts each neuron's synapses by ring offset (the kernel's order) and returns the
        permutation applied to `synapses`, or None when they were already in that order.
        """
        cfg = self.cfg
        n = self.layout.n
        self._model = MODEL_IDS[cfg.neurons.model]
        self._dt = float(cfg.dt_ms)
        self._n_sub = izhikevich_substeps(self._dt)
        self._noise_steps = round(cfg.noise.interval_ms / self._dt)
        delay = delay_steps(self.synapses.delay_ms, self._dt)
        self._n_slots = int(delay.max()) + 1 if delay.size else 2
        target = kernels.ring_targets(delay, self.synapses.post, n)
        # each neuron's synapses in ascending ring offset (the kernel relies on it); a post
        # appears once per row, so this order changes no sum and no spike
        order = kernels.row_order(self.synapses.indptr, target)
        if order is not None:
            self.synapses = self.synapses.permuted(order)
            target = target[order]
        self._target = target
        self._pre = self.synapses.pre()
        self._is_exc = (self.layout.cell_type == EXCITATORY).astype(np.bool_)
        in_order = np.argsort(self.synapses.post, kind="stable")
        self._in_syn = in_order.astype(np.int64)
        self._in_indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(self.synapses.post, minlength=n), out=self._in_indptr[1:])
        st = cfg.stdp
        self._stdp = (
            bool(st.enabled),
            float(st.a_plus_mv),
            float(st.a_minus_mv),
            math.exp(-self._dt / st.tau_plus_ms),
            math.exp(-self._dt / st.tau_minus_ms),
            float(st.w_max_mv),
        )
        self._dep_tau_steps = cfg.depression.tau_rec_ms / self._dt
        inh = self.layout.cell_type != EXCITATORY
        ada = cfg.adaptation
        self._adapt_on = ada.enabled and self._model == MODEL_IDS["izhikevich"]
        inc = np.where(inh, ada.increment_of(True), ada.increment_of(False))
        # Excitatory cells at the chattering end of the RS -> CH spread (reset c at or above
        # adaptation.exempt_from_reset_mv): they do not adapt, and the paper's protocols,
        # which stimulate regular-spiking cells, leave them out (lab/reproduce.py).
        self.chattering_like = np.zeros(n, dtype=bool)
        if self._adapt_on and ada.exempt_from_reset_mv is not None:
            limit = kernels.STATE_DTYPE(ada.exempt_from_reset_mv)
            self.chattering_like = ~inh & (self.params[2] >= limit)
            inc[self.chattering_like] = 0.0
        self._adapt_inc = inc.astype(kernels.STATE_DTYPE)
        decay = math.exp(-self._dt / ada.tau_ms)
        period = kernels.adaptation_period(decay) if self._adapt_on else 1
        self._adapt_g = kernels.adaptation_factors(decay, period)
        slow = cfg.slow_current
        self._slow_on = slow.share > 0.0 and self._model == MODEL_IDS["izhikevich"]
        self._slow_gain = kernels.STATE_DTYPE(slow.share / slow.tau_ms)
        self._slow_decay = kernels.STATE_DTYPE(math.exp(-self._dt / slow.tau_ms))
        self._noise_mean = np.empty(n, dtype=kernels.STATE_DTYPE)
        self._noise_sd = np.empty(n, dtype=kernels.STATE_DTYPE)
        for flag in (False, True):
            mean, sd = cfg.noise.of_population(flag)
            self._noise_mean[inh == flag] = mean
            self._noise_sd[inh == flag] = sd
        self._stim_cur = np.zeros(n, dtype=kernels.STATE_DTYPE)
        self._out_neuron = np.zeros(max(4 * n, 4096), dtype=np.int32)
        self._out_step = np.zeros(self._out_neuron.size, dtype=np.int64)
        self._pulse_current_per_ua = cfg.stimulation.model_current_per_ua
        self._neuron_spikes = Spikes.concat([])
        return order

    def _reset_state(self) -> None:
        n = self.layout.n
        self.step = 0
        v, aux = initial_state(self.cfg, self.params.astype(np.float64))
        self.v = v.astype(kernels.STATE_DTYPE)
        self.aux = aux.astype(kernels.STATE_DTYPE)
        self.ring = np.zeros((self._n_slots, n), dtype=np.float32)  # mV due per step
        self.noise_cur = np.zeros(n, dtype=kernels.STATE_DTYPE)
        self.noise_state = np.zeros((4, n), dtype=np.uint32)
        noise_seed = np.random.SeedSequence([self.seed, 0x0153]).generate_state(1, np.uint64)[0]
        kernels.seed_noise_state(np.uint64(noise_seed), self.noise_state)
        self.dep_x = np.ones(n)
        self.dep_last = np.full(n, _NEVER, dtype=np.int64)
        self.x_pre = np.zeros(n)
        self.y_post = np.zeros(n)
        self.weight = self.synapses.weight_mv.copy()
        self._pending = _PendingPulses.empty()

    # ------------------------------------------------------------------ public view
    @property
    def t_ms(self) -> float:
        """Current simulated time (ms): steps done × dt."""
        return self.step * self._dt

    @property
    def n_neurons(self) -> int:
        """Number of neurons."""
        return self.layout.n

    @property
    def channels(self) -> Channels:
        """The channel layout: the neurons themselves, or the virtual MEA's electrodes."""
        if self.mea is None:
            return Channels(
                channel=np.arange(self.layout.n, dtype=np.uint32),
                x_um=self.layout.x_um.copy(),
                y_um=self.layout.y_um.copy(),
                cell_type=self.layout.cell_type.copy(),
                kind="neuron",
            )
        return Channels(
            channel=np.arange(self.mea.n_electrodes, dtype=np.uint32),
            x_um=self.mea.x_um.copy(),
            y_um=self.mea.y_um.copy(),
            cell_type=None,
            kind="electrode",
        )

    @property
    def neuron_spikes(self) -> Spikes:
        """Neuron-level spikes of the most recent `run()` (`channel` holds the neuron index)."""
        return self._neuron_spikes

    @property
    def adaptation_increment(self) -> np.ndarray:
        """Each neuron's rise of its adaptation current per spike (float32[n], model current
        units, a copy): its population's increment, 0 for chattering-like cells, all 0 when
        the adaptation is off."""
        if not self._adapt_on:
            return np.zeros(self.layout.n, dtype=np.float32)
        return self._adapt_inc.copy()

    def adaptation_current(self) -> np.ndarray:
        """Each neuron's spike-frequency adaptation current, as the next step will use it.

        Returns
        -------
        float32[n_neurons]
            Model current units (mV/ms for Izhikevich neurons), a copy; zeros when the
            adaptation is off. The state keeps amplitudes (``aux[2]``) that the kernel scales by
            a decay factor depending on the step (``kernels.advance``).
        """
        if not self._adapt_on:
            return np.zeros(self.layout.n, dtype=np.float32)
        period = self._adapt_g.size - 1
        j = self.step % period
        factor = self._adapt_g[period] if j == 0 else self._adapt_g[j]
        return (self.aux[2] * factor).astype(np.float32)

    def potentials(self) -> np.ndarray:
        """A snapshot of the membrane potentials.

        Returns
        -------
        float32[n_neurons]
            Each neuron's membrane potential (mV) now, a copy.
        """
        return self.v.astype(np.float32)

    # ------------------------------------------------------------------ running
    def run(self, duration_ms: float, pulses: Pulses | None = None) -> Spikes:
        """Advance by `duration_ms` (whole steps); return the spikes in channel space.

        Parameters
        ----------
        duration_ms : float
            Simulated time to advance; must be a non-negative multiple of `dt_ms`.
        pulses : Pulses, optional
            Current pulses in channel space, onsets relative to the start of this call. Parts
            beyond the end of the call (or onsets beyond it) are carried into the next calls.

        Returns
        -------
        Spikes
            Channel spikes with absolute times, sorted by time. Neuron-level spikes of the
            same call are in `neuron_spikes`.
        """
        n_steps = steps_of(duration_ms, self._dt)
        if pulses is not None and not isinstance(pulses, Pulses):
            raise TypeError(f"pulses must be a Pulses record, got {type(pulses).__name__}")
        if pulses is not None and len(pulses):
            self._add_pulses(pulses)
        k0 = self.step
        k1 = k0 + n_steps
        self._pending = self._pending.alive_after(k0)
        pend = self._pending
        n_out = 0
        neurons: list[np.ndarray] = []
        steps: list[np.ndarray] = []
        groups = (  # the parts of the model, as `kernels.advance` takes them
            (self._model, self._dt, self._n_sub, self.v, self.aux, self.params),
            (self.ring, self.synapses.indptr, self.synapses.post, self.weight, self._target),
            (float(self.cfg.depression.u), self._dep_tau_steps, self.dep_x, self.dep_last),
            (self._noise_mean, self._noise_sd, self._noise_steps, self.noise_state, self.noise_cur),
            (pend.neuron, pend.current, pend.start, pend.end, self._stim_cur),
            (
                *self._stdp,
                self.x_pre,
                self.y_post,
                self._in_indptr,
                self._in_syn,
                self._pre,
                self._is_exc,
            ),
            (  # the adaptation amplitudes live in aux[2] (a free row of the Izhikevich state)
                self.aux[2] if self._adapt_on else None,
                self._adapt_inc if self._adapt_on else None,
                self._adapt_g,
            ),
            (  # the slow synaptic current lives in aux[3] (free in the Izhikevich state)
                self.aux[3] if self._slow_on else None,
                self._slow_gain,
                self._slow_decay,
            ),
            (self._out_neuron, self._out_step),
        )
        k = k0
        while k < k1:
            done, n_out = kernels.advance(k1 - k, k, *groups, 0)
            k += done
            self.step = k
            neurons.append(self._out_neuron[:n_out].copy())
            steps.append(self._out_step[:n_out].copy())
        if len(neurons) == 1:
            neuron, step = neurons[0], steps[0]
        else:
            neuron = np.concatenate(neurons) if neurons else np.zeros(0, np.int32)
            step = np.concatenate(steps) if steps else np.zeros(0, np.int64)
        t_ms = (step + 1).astype(np.float64) * self._dt
        self._neuron_spikes = Spikes(neuron.astype(np.uint32), t_ms)
        if self.mea is None:
            return self._neuron_spikes
        return on_electrodes(self.mea, neuron, t_ms)

    def _add_pulses(self, pulses: Pulses) -> None:
        mea = self.mea
        n_channels = self.layout.n if mea is None else mea.n_electrodes
        none = _PendingPulses.NONE
        pend = self._pending
        top, arrays = pulse_kernels.scheduled(
            pend.neuron, pend.current, pend.start, pend.end,
            pulses.channel, pulses.amplitude_ua, pulses.width_ms, pulses.onset_ms,
            self.step, self._dt, self._pulse_current_per_ua, n_channels,
            none if mea is None else mea.stim_indptr, none if mea is None else mea.stim_neuron,
            mea is not None,
        )  # fmt: skip
        if top >= 0:
            raise PulseError(f"pulses.channel {top} out of range (network has {n_channels})")
        self._pending = _PendingPulses.of(arrays)

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, np.ndarray]:
        """Everything that evolves during `run()`, as copies of plain arrays.

        Returns
        -------
        dict of str to numpy.ndarray
            ``step``, the neuron state (``v``, ``aux``), the delay ring, noise, depression and
            STDP state, the current weights and the pending pulses; `set_state` takes it back.
        """
        return {
            "step": np.array(self.step, dtype=np.int64),
            "v": self.v.copy(),
            "aux": self.aux.copy(),
            "ring": self.ring.copy(),
            "noise_cur": self.noise_cur.copy(),
            "noise_state": self.noise_state.copy(),
            "dep_x": self.dep_x.copy(),
            "dep_last": self.dep_last.copy(),
            "x_pre": self.x_pre.copy(),
            "y_post": self.y_post.copy(),
            "weight": self.weight.copy(),
            "pulse_neuron": self._pending.neuron.copy(),
            "pulse_current": self._pending.current.copy(),
            "pulse_start": self._pending.start.copy(),
            "pulse_end": self._pending.end.copy(),
        }

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        """Restore what `get_state` returned.

        Parameters
        ----------
        state : dict of str to numpy.ndarray
            From `get_state` of a network with the same config and seed; every array must
            have the shape of the current one (copied in, converted to its dtype).
        """
        for key in (
            "v",
            "aux",
            "ring",
            "noise_cur",
            "noise_state",
            "dep_x",
            "dep_last",
            "x_pre",
            "y_post",
            "weight",
        ):
            cur = getattr(self, key)
            new = np.asarray(state[key])
            if new.shape != cur.shape:
                raise ValueError(f"state.{key} has shape {new.shape}, expected {cur.shape}")
            setattr(self, key, new.astype(cur.dtype, copy=True))
        self.step = int(state["step"])
        self._pending = _PendingPulses(
            np.asarray(state["pulse_neuron"], np.int64),
            np.asarray(state["pulse_current"], np.float64),
            np.asarray(state["pulse_start"], np.int64),
            np.asarray(state["pulse_end"], np.int64),
        )

    def warm_up(self) -> None:
        """Compile the kernels: one stimulated run of 10 ms on a saved state, then the state
        restored exactly. A first call of a kernel compiles it (seconds, or a cache read):
        whatever runs the network in real time calls this before its clock starts."""
        state = self.get_state()
        self.run(10.0, Pulses.single([int(self.channels.channel[0])], 1.0, 1.0))
        self.set_state(state)

    def save(self, path: str | Path) -> None:
        """Write config, seed, connectivity and state to one file.

        Parameters
        ----------
        path : str or Path
            Written exactly there, in ``.npz`` format (no suffix added); `load` reads it.
        """
        syn = self.synapses
        meta = {"version": _STATE_VERSION, "seed": self.seed, "config": config_to_dict(self.cfg)}
        with open(path, "wb") as fh:  # exactly this path (np.savez would add .npz)
            np.savez(
                fh,
                meta=np.array(json.dumps(meta)),
                syn_indptr=syn.indptr,
                syn_post=syn.post,
                syn_weight_mv=syn.weight_mv,
                syn_delay_ms=syn.delay_ms,
                syn_distance_um=syn.distance_um,
                cell_type=self.layout.cell_type,
                params=self.params,
                **self.get_state(),
            )

    @classmethod
    def load(cls, path: str | Path) -> Network:
        """Rebuild a network saved by `save`.

        Parameters
        ----------
        path : str or Path
            A file written by `save` (state version 2).

        Returns
        -------
        Network
            At the saved step; running on gives the spikes the saved network would have given.

        Raises
        ------
        ValueError
            The file holds another state version (version 1 used a noise generator this
            version no longer has).
        """
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            version = meta.get("version")
            if version == 1:
                raise ValueError(
                    f"{path}: state version 1 was saved with the former noise generator "
                    "(xoroshiro128+), which this version no longer has, so the run cannot be "
                    "continued as it would have gone on; rebuild the network from its config "
                    "and seed (Network(cfg, seed)) and run it again"
                )
            if version != _STATE_VERSION:
                raise ValueError(f"{path}: state version {version} is not supported")
            cfg = config_from_dict(meta["config"])
            net = cls.__new__(cls)
            net.cfg = cfg
            net.seed = int(meta["seed"])
            rng = np.random.default_rng([net.seed, 0x5E7])
            net.layout = build_layout(cfg.layout, rng)
            net.layout.cell_type[:] = data["cell_type"]
            net.synapses = Synapses(
                data["syn_indptr"], data["syn_post"], data["syn_weight_mv"],
                data["syn_delay_ms"], data["syn_distance_um"],
            )  # fmt: skip
            net.params = data["params"].astype(kernels.STATE_DTYPE)
            net.mea = build_mea(cfg.mea, net.layout) if cfg.channels == "mea" else None
            order = net._derive()
            net._reset_state()
            state = {k: data[k] for k in data.files}
            if order is not None:  # saved before rows were kept in kernel order
                state["weight"] = np.asarray(state["weight"])[order]
            net.set_state(state)
        return net


class _PendingPulses:
    """Pulses in neuron space on absolute steps [start, end), kept sorted by start (stably:
    among equal starts, in the order they were added)."""

    __slots__ = ("neuron", "current", "start", "end")
    NONE = np.zeros(0, dtype=np.int64)  # no electrodes' neurons (a culture without a MEA)

    def __init__(self, neuron, current, start, end):
        self.neuron = np.ascontiguousarray(neuron, dtype=np.int64)
        self.current = np.ascontiguousarray(current, dtype=np.float64)
        self.start = np.ascontiguousarray(start, dtype=np.int64)
        self.end = np.ascontiguousarray(end, dtype=np.int64)

    @classmethod
    def of(cls, arrays: tuple[np.ndarray, ...]) -> _PendingPulses:
        """From a kernel's (neuron, current, start, end): contiguous arrays of the dtypes."""
        pending = cls.__new__(cls)
        pending.neuron, pending.current, pending.start, pending.end = arrays
        return pending

    @classmethod
    def empty(cls) -> _PendingPulses:
        z = np.zeros(0, dtype=np.int64)
        return cls(z, np.zeros(0), z, z)

    def alive_after(self, k: int) -> _PendingPulses:
        """Drop pulses that ended before step k (keeps the per-step kernel loop short)."""
        if not self.end.size:
            return self
        changed, arrays = pulse_kernels.alive_after(
            self.neuron, self.current, self.start, self.end, k
        )
        return _PendingPulses.of(arrays) if changed else self
