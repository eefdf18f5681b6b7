"""The culture of a culture file simulated by NEST instead of sim_network's own kernels.

``NestNetwork(cfg, seed, threads)`` builds the same culture as ``Network(cfg, seed)`` — the
same layout, cell types, per-neuron Izhikevich parameters and synapses (drawn by
``Network``'s own seeded sampler and handed to NEST as explicit arrays) — and runs it with
the `NEST simulator <https://www.nest-simulator.org>`_: threads on one host, MPI across
hosts. Its ``run(duration_ms, pulses)`` takes and returns what ``Network.run`` does, so the
culture endpoint serves either one (``culture.kind = "nest"``). A library: no bus here.

How each part of the culture file is built (docs/nest.md says why, and what differs):

==================  ========================================================================
culture file        NEST
==================  ========================================================================
``neurons``         ``izhikevich`` with ``consistent_integration`` (forward Euler at dt,
                    spike inputs added to V_m as jumps in mV), each neuron's a, b, c, d;
                    V_th 30 mV, V_min −100 mV (sim_network's peak and floor)
``adaptation``,     ``izhikevich_neuvision`` instead (`sim_network.nest_module`, built on
``slow_current``    first use): ``izhikevich`` with the adaptation current (each neuron's
                    increment, ``tau_adapt``) and the slow current (``slow_share``,
                    ``tau_slow``)
``connectivity``    ``nest.Connect`` of the sampler's arrays (pre, post, weight in mV,
                    delay in whole steps as sim_network rounds it, less one:
                    `nest_delay_steps`)
``depression``      ``tsodyks2_synapse`` with U = ``u``, no facilitation, weight w / U (its
                    first spike delivers U·w / U = w; later ones x·w, as sim_network's
                    per-neuron resources, which every synapse of a neuron shares)
``stdp``            ``stdp_synapse`` (additive: mu 0, lambda a+/w_max, alpha a−/a+) on the
                    excitatory synapses, ``tau_minus`` on the neurons
``noise``           the culture's own noise (sim_network's per-neuron generators,
                    the same currents in the same windows): drawn by each
                    ``izhikevich_neuvision`` neuron itself, or replayed to ``izhikevich``
                    through one ``step_current_generator`` per neuron (`_NoiseReplay`);
                    or, with ``noise_source = "nest"``, NEST's ``noise_generator`` per
                    population (Gaussian, same mean and s.d.)
pulses              each neuron's ``I_e``, set between ``nest.Run`` calls cut at the pulses'
                    edges: a pulse acts on exactly the steps it acts on in sim_network
==================  ========================================================================

Each ``run()`` is one ``nest.Prepare()`` … ``nest.Run`` … ``nest.Cleanup()``: the spikes of
the call are read from a ``spike_recorder`` in memory, which NEST lets be emptied only
outside ``Prepare``. A feature that NEST cannot express is refused by name
(`refusals`), never dropped. NEST holds one network per process: building a second
``NestNetwork`` retires the first.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import os
import queue
import threading
import warnings
from concurrent.futures import Future

import numpy as np
from numba import njit

from settings import ConfigError
from sim_network import nest_module
from sim_network.config import NetworkConfig
from sim_network.connectivity import delay_steps
from sim_network.kernels import IZH_V_PEAK_MV, STATE_DTYPE, V_FLOOR_MV, fill_noise
from sim_network.layout import EXCITATORY, Layout
from sim_network.network import Network, on_electrodes, steps_of
from sim_network.neurons import initial_state
from sim_network.records import Channels, PulseError, Pulses, Spikes

INSTALL_HINT = "pip install 'neuvision[nest]' (the nest-simulator wheel: threads, no MPI)"

#: The sections of a culture file this module knows: built in NEST, or checked and refused.
#: A test fails when the culture file gains a section that is not listed here.
KNOWN_SECTIONS = (
    "dt_ms", "channels", "layout", "neurons", "connectivity", "depression", "noise",
    "stimulation", "stdp", "mea", "adaptation", "slow_current",
)  # fmt: skip

# Launchers set these in every process of an MPI job (Open MPI, MPICH/Hydra and Intel MPI,
# MVAPICH): how a NEST without MPI notices that it was started as one of several ranks.
_MPI_SIZE_VARIABLES = ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "MV2_COMM_WORLD_SIZE")

_owner: NestNetwork | None = None  # the NestNetwork whose network the NEST kernel holds


class NestRetired(RuntimeError):
    """This NestNetwork's network was replaced: NEST holds one network per process."""


class MpiMismatch(RuntimeError):
    """This process's MPI job and its NEST do not fit (a NEST without MPI under mpirun)."""


class _NestThread:
    """The one thread that imports NEST and makes every call to it, in the order asked.

    NEST must be called from the thread that initialised it (a call from another thread
    crashes the process: NEST 3.10), while an endpoint steps on whichever thread its
    messages arrive. Jobs run one at a time; `submit` returns at once, `call` waits.
    """

    def __init__(self):
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self.thread = threading.Thread(target=self._serve, name="nest", daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        while True:
            future, fn, args = self._jobs.get()
            if future.set_running_or_notify_cancel():
                try:
                    future.set_result(fn(*args))
                except BaseException as exc:  # the caller's to raise
                    future.set_exception(exc)

    def submit(self, fn, *args) -> Future:
        """Queue ``fn(*args)`` on the NEST thread; its future."""
        future: Future = Future()
        self._jobs.put((future, fn, args))
        return future

    def call(self, fn, *args):
        """``fn(*args)`` on the NEST thread: its value, or its exception raised here."""
        if threading.current_thread() is self.thread:
            return fn(*args)
        return self.submit(fn, *args).result()


_nest_thread: _NestThread | None = None
_nest_thread_lock = threading.Lock()


def nest_thread() -> _NestThread:
    """The process's NEST thread (started on first use)."""
    global _nest_thread
    with _nest_thread_lock:
        if _nest_thread is None:
            _nest_thread = _NestThread()
        return _nest_thread


def nest_available() -> bool:
    """Whether NEST can be imported here (without importing it).

    Returns
    -------
    bool
        True when the ``nest`` package (PyNEST, e.g. the ``nest-simulator`` wheel) is found.
    """
    return importlib.util.find_spec("nest") is not None


def import_nest():
    """Import NEST without its banner, its messages limited to errors.

    Returns
    -------
    module
        ``nest``.

    Raises
    ------
    ImportError
        NEST is not installed; the message says how to install it.
    """
    os.environ.setdefault("PYNEST_QUIET", "1")  # no banner on stdout
    try:
        import nest
    except ImportError as exc:
        raise ImportError(f"the NEST culture needs NEST: {INSTALL_HINT} ({exc})") from exc
    nest.verbosity = nest.VerbosityLevel.ERROR  # no warning per Run not a min_delay multiple
    return nest


def refusals(cfg: NetworkConfig) -> list[str]:
    """What of this culture NEST cannot express, each named by its key, with the reason.

    Parameters
    ----------
    cfg : NetworkConfig

    Returns
    -------
    list of str
        Empty when NEST builds this culture as sim_network does.
    """
    out = []
    model = cfg.neurons.model
    if model == "lif":
        out.append(
            "neurons.model = 'lif': the NEST culture is built of Izhikevich neurons only "
            "(NEST's iaf_psc_delta could take it; not built here)"
        )
    elif model == "hh":
        out.append(
            "neurons.model = 'hh': NEST's Hodgkin-Huxley neurons take synaptic input as "
            "alpha-shaped currents, not as the voltage jumps of this culture's synapses"
        )
    st = cfg.stdp
    if st.enabled and cfg.depression.u > 0:
        out.append(
            f"stdp.enabled with depression.u = {cfg.depression.u}: NEST has no synapse model "
            "with both STDP and short-term depression (stdp_synapse and tsodyks2_synapse are "
            "separate); set depression.u = 0 or leave STDP off"
        )
    if st.enabled and st.a_plus_mv == 0 and st.a_minus_mv > 0:
        out.append(
            "stdp.a_plus_mv = 0 with stdp.a_minus_mv > 0: NEST's stdp_synapse scales "
            "depression by its potentiation step (alpha * lambda), so it cannot depress alone"
        )
    return out


def needs_module(cfg: NetworkConfig) -> bool:
    """Whether the culture needs ``izhikevich_neuvision`` (its adaptation or slow current)
    rather than NEST's own ``izhikevich``."""
    return cfg.adaptation.enabled or cfg.slow_current.share > 0


def check_expressible(cfg: NetworkConfig, prefix: str = "") -> None:
    """Raise `ConfigError` naming every feature of ``cfg`` that NEST cannot express.

    Parameters
    ----------
    cfg : NetworkConfig
    prefix : str
        Put before each key (``culture.params.``).

    Raises
    ------
    ConfigError
        ``the NEST culture cannot express: <key> ...: <why>; ...``.
    """
    found = refusals(cfg)
    if found:
        raise ConfigError(
            "the NEST culture cannot express: " + "; ".join(prefix + item for item in found)
        )


def set_each(nodes, values: list[dict]) -> None:
    """Set each node's parameters: ``values[i]`` for ``nodes[i]`` (on the NEST thread).

    PyNEST's ``NodeCollection.set`` first asks every node whether it is local, at ~6 µs a
    node (8x the setting itself); NEST's low-level setter does not (a node of another MPI
    rank is skipped there as well). Falls back to ``set`` if PyNEST lacks it.

    Parameters
    ----------
    nodes : nest.NodeCollection
    values : list of dict
        One dict of parameter names to values per node, in the collection's order.
    """
    try:
        from nest.nestkernel_api import llapi_set_nc_status
    except ImportError:
        nodes.set(values)
        return
    llapi_set_nc_status(nodes._datum, values)


def _launched_ranks() -> int:
    """How many ranks the MPI launcher started (1 when not started by one)."""
    for name in _MPI_SIZE_VARIABLES:
        value = os.environ.get(name, "")
        if value.isdigit():
            return int(value)
    return 1


def mpi_world(nest):
    """The MPI job this process is part of, as NEST sees it.

    Parameters
    ----------
    nest : module

    Returns
    -------
    comm, rank, size
        ``mpi4py``'s ``COMM_WORLD``, this process's rank and the number of ranks; (None, 0,
        1) when NEST runs in one process.

    Raises
    ------
    MpiMismatch
        Started as one of several MPI ranks with a NEST built without MPI (each copy would
        simulate the whole culture and talk to the bus), or a NEST with MPI and no mpi4py.
    """
    size = int(nest.num_processes)
    if size == 1:
        launched = _launched_ranks()
        if launched > 1:
            raise MpiMismatch(
                f"started as one of {launched} MPI ranks, but this NEST is built without MPI "
                "(the nest-simulator wheel is): each rank would simulate the whole culture. "
                "Build NEST with -Dwith-mpi=ON (docs/nest.md), or run one process with threads"
            )
        return None, 0, 1
    try:
        from mpi4py import MPI
    except ImportError as exc:
        raise MpiMismatch(
            f"NEST runs on {size} MPI ranks; the culture gathers each step's spikes to rank 0 "
            f"with mpi4py, which is missing (pip install mpi4py): {exc}"
        ) from exc
    comm = MPI.COMM_WORLD
    if comm.Get_size() != size:
        raise MpiMismatch(f"mpi4py sees {comm.Get_size()} ranks, NEST {size}")
    return comm, int(nest.Rank()), size


def nest_seed(seed: int) -> int:
    """NEST's ``rng_seed`` (in [1, 2**31 - 1]) for a culture seed.

    Parameters
    ----------
    seed : int

    Returns
    -------
    int
    """
    word = np.random.SeedSequence([int(seed), 0x4E57]).generate_state(1, np.uint32)[0]
    return int(word) % (2**31 - 2) + 1


def nest_delay_steps(steps: np.ndarray) -> np.ndarray:
    """NEST's delays (in steps) that make a jump arrive when sim_network's arrives.

    sim_network adds a jump with a delay of d steps, sent by a spike found in step k, to V
    at the start of step k + d, before that step's Euler update; NEST adds it at the end of
    step k + delay, after the update. The same moment is ``delay = d - 1``; the update of
    step k + d then starts from the jumped V in both. NEST's shortest delay is one step:
    a one-step delay of sim_network stays one step (its jump lands a step later).

    Parameters
    ----------
    steps : int array
        sim_network's delays (`connectivity.delay_steps`, at least 1).

    Returns
    -------
    int64 array
    """
    return np.maximum(np.asarray(steps, dtype=np.int64) - 1, 1)


@dataclasses.dataclass
class _Pending:
    """Pulses in neuron space on absolute steps [start, end), with their model current."""

    neuron: np.ndarray  # int64
    current: np.ndarray  # float64
    start: np.ndarray  # int64
    end: np.ndarray  # int64

    @classmethod
    def empty(cls) -> _Pending:
        z = np.zeros(0, dtype=np.int64)
        return cls(z, np.zeros(0), z, z)

    def plus(self, other: _Pending) -> _Pending:
        return _Pending(
            *(np.concatenate((getattr(self, f), getattr(other, f))) for f in _PENDING_FIELDS)
        )

    def alive_after(self, k: int) -> _Pending:
        keep = self.end > k
        return _Pending(*(getattr(self, f)[keep] for f in _PENDING_FIELDS))


_PENDING_FIELDS = ("neuron", "current", "start", "end")


NOISE_SOURCES = ("culture", "nest")

#: Noise windows loaded at once into each step_current_generator (at most; fewer for large
#: cultures, so that NEST holds at most ~REPLAY_MAX_VALUES values at a time).
REPLAY_WINDOWS = 1000
REPLAY_MAX_VALUES = 8_000_000
#: Generators are loaded in this many groups at staggered times, so that no single step
#: pays for loading them all.
REPLAY_GROUPS = 50


@njit(cache=True, nogil=True)
def _draw_windows(state, mean, sd, out):
    """Draw ``out.shape[0]`` consecutive noise windows (rows of ``out``), as
    `kernels.fill_noise` draws one: each neuron's generator advanced once per window."""
    for w in range(out.shape[0]):
        fill_noise(out[w], state, mean, sd)


class _NoiseReplay:
    """The culture's own noise — sim_network's per-neuron generators, the same currents in
    the same windows — delivered by one ``step_current_generator`` per neuron.

    A generator's amplitude stamped at step T reaches its neuron's Euler update of step
    T + D (D: the connection's delay in steps); window w, which sim_network applies from
    step w·m on, is stamped (w·m − D). The windows that start before step D + 1 cannot be
    stamped so early: `early` holds them, and `NestNetwork` puts them into I_e. Setting a
    generator's amplitudes replaces its whole list, so a load repeats the windows loaded
    before that it has not reached yet.
    """

    def __init__(self, nest, nodes, state0, mean, sd, window_steps, delay_steps, dt):
        n = len(nodes)
        self.m = int(window_steps)
        self.d = int(delay_steps)
        self.dt = dt
        self.state = state0.copy()
        self.mean = mean
        self.sd = sd
        self.gens = nest.Create("step_current_generator", n)
        nest.Connect(self.gens, nodes, "one_to_one", syn_spec={"delay": self.d * dt})
        self.first = math.ceil((self.d + 1) / self.m)  # the first window a generator carries
        self.early = np.zeros((self.first, n), dtype=STATE_DTYPE)
        _draw_windows(self.state, self.mean, self.sd, self.early)
        self.chunk = max(1, min(REPLAY_WINDOWS, REPLAY_MAX_VALUES // max(n, 1)))
        groups = min(REPLAY_GROUPS, n)
        self.bounds = np.linspace(0, n, groups + 1).round().astype(np.int64)
        # each group's windows loaded into its generators: from held_from[g] on, values held
        self.held_from = np.full(groups, self.first, dtype=np.int64)
        self.held = [np.zeros((0, hi - lo), STATE_DTYPE) for lo, hi in self._ranges()]
        # staggered first loads: group g gets (g + 1) / groups of a chunk
        self.size = np.maximum(1, (self.chunk * (np.arange(groups) + 1)) // groups)

    def _ranges(self):
        return zip(self.bounds[:-1], self.bounds[1:], strict=True)

    def load(self, k0: int, k1: int) -> None:
        """Before a Run of steps [k0, k1): load every group whose loaded windows run out."""
        for g, (lo, hi) in enumerate(self._ranges()):
            next_w = self.held_from[g] + len(self.held[g])
            if next_w * self.m - self.d - 1 >= k1:
                continue  # its next window is stamped after this Run
            size = int(self.size[g])
            while (next_w + size) * self.m - self.d - 1 < k1:
                size += self.chunk  # a long run() call: load what it needs at once
            new = np.empty((size, hi - lo), dtype=STATE_DTYPE)
            _draw_windows(self.state[:, lo:hi], self.mean[lo:hi], self.sd[lo:hi], new)
            # the windows loaded before whose stamp this Run has yet to reach (T > k0)
            start = max(self.held_from[g], -(-(k0 + self.d + 1) // self.m))
            values = np.concatenate((self.held[g][start - self.held_from[g] :], new))
            w = start + np.arange(len(values))
            times = (w * self.m - self.d) * self.dt
            cols = np.ascontiguousarray(values.T, dtype=np.float64)
            set_each(
                self.gens[lo:hi],
                [{"amplitude_times": times, "amplitude_values": c} for c in cols],
            )
            self.held[g], self.held_from[g] = values, start
            self.size[g] = self.chunk


class NestNetwork:
    """The culture of ``cfg`` built and run in NEST; ``run()`` as `Network.run`.

    Parameters
    ----------
    cfg : NetworkConfig
        The culture; a feature NEST cannot express raises `ConfigError` (`refusals`).
    seed : int
        Seeds the layout, connectivity and heterogeneity (``Network``'s sampler: the same
        arrays as ``Network(cfg, seed)``) and NEST's random numbers (the noise). NEST gives
        the same spikes again for the same seed and the same number of threads × ranks.
    threads : int
        NEST's threads in this process (``local_num_threads``).
    noise_source : {"culture", "nest"}
        ``"culture"`` (default): the culture's own noise — the same currents in the same
        windows as ``Network(cfg, seed)`` — replayed through one ``step_current_generator``
        per neuron (loading them costs ~65 ns per neuron and window). ``"nest"``: NEST's
        ``noise_generator`` per population, Gaussian draws of the same mean and s.d. from
        NEST's random numbers: cheaper at scale, but not the culture's noise, and the
        culture's network bursts depend on it (docs/nest.md: about a third as many).

    Notes
    -----
    Every call to NEST is made on one thread of this process (`nest_thread`), whichever
    thread calls the methods. Under ``mpirun`` with a NEST built with MPI every rank
    constructs it and builds its share of the neurons; rank 0 calls the methods and the
    other ranks call `follow` (the culture endpoint does this): each call of rank 0 that
    touches NEST is sent to the other ranks first, and each step's spikes are gathered to
    rank 0 (mpi4py).
    """

    def __init__(
        self, cfg: NetworkConfig, seed: int = 0, threads: int = 1, noise_source: str = "culture"
    ):
        if not isinstance(cfg, NetworkConfig):
            raise TypeError(f"cfg must be a NetworkConfig, got {type(cfg).__name__}")
        check_expressible(cfg)
        if int(threads) < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        if noise_source not in NOISE_SOURCES:
            raise ValueError(f"noise_source must be one of {NOISE_SOURCES}, got {noise_source!r}")
        worker = nest_thread()
        self.nest = worker.call(import_nest)
        self.comm, self.rank, self.n_ranks = worker.call(mpi_world, self.nest)
        self.cfg = cfg
        self.seed = int(seed)
        self.threads = int(threads)
        self.noise_source = noise_source
        sampler = Network(cfg, seed)  # the same seeded draws as the sim_network culture
        self.layout: Layout = sampler.layout
        self.synapses = sampler.synapses
        self.params = sampler.params.astype(np.float64)  # a, b, c, d as sim_network holds them
        self.mea = sampler.mea
        self._channels: Channels = sampler.channels
        self._noise_state0 = sampler.noise_state.copy()  # its noise generators, as seeded
        inhibitory = self.layout.cell_type != EXCITATORY
        self._noise_mean = np.empty(self.layout.n, dtype=STATE_DTYPE)
        self._noise_sd = np.empty(self.layout.n, dtype=STATE_DTYPE)
        for flag in (False, True):
            self._noise_mean[inhibitory == flag], self._noise_sd[inhibitory == flag] = (
                cfg.noise.of_population(flag)
            )
        self._dt = float(cfg.dt_ms)
        self.chattering_like = sampler.chattering_like  # as Network: cells that do not adapt
        self._adapt_increment = sampler.adaptation_increment.astype(np.float64)
        del sampler
        self._module = nest_module.module_path() if needs_module(cfg) else None
        self._rebuilding: Future | None = None
        self._neuron_spikes = Spikes.concat([])
        worker.call(self._build)  # every rank builds its share (none is following yet)

    # ------------------------------------------------------------------ public view
    @property
    def n_neurons(self) -> int:
        """Number of neurons."""
        return self.layout.n

    @property
    def channels(self) -> Channels:
        """The channel layout, as `Network.channels` (neurons, or the virtual MEA)."""
        return self._channels

    @property
    def t_ms(self) -> float:
        """Simulated time since the network was built (ms)."""
        return self.step * self._dt

    @property
    def neuron_spikes(self) -> Spikes:
        """Neuron-level spikes of the most recent `run` (on rank 0)."""
        return self._neuron_spikes

    @property
    def n_connections(self) -> int:
        """Connections between neurons that NEST holds (of all ranks)."""
        return self._call("_n_connections")

    def _n_connections(self) -> int:
        # each rank holds the connections to its own neurons, device connections included
        per_neuron = self._device_connections // self.layout.n
        local = int(self.nest.num_connections) - per_neuron * self._n_local
        return local if self.comm is None else self.comm.allreduce(local)

    # ------------------------------------------------------------------ building
    def _build(self) -> None:
        """(Re)build the whole network in a fresh NEST kernel, at time 0 (NEST thread)."""
        global _owner
        nest = self.nest
        cfg = self.cfg
        n = self.layout.n
        syn = self.synapses
        dt = self._dt
        _owner = self
        nest.ResetKernel()
        nest.set(resolution=dt, local_num_threads=self.threads, rng_seed=nest_seed(self.seed))
        steps = nest_delay_steps(delay_steps(syn.delay_ms, dt))
        d_min = int(steps.min()) if steps.size else 1
        d_max = int(steps.max()) if steps.size else 1
        # Devices are connected with the shortest synaptic delay: a shorter one would set
        # NEST's communication interval (min_delay), and with it the cost of each step.
        # (NEST truncates these two to whole steps: half a step more lands on the step.)
        nest.set(min_delay=(d_min + 0.5) * dt, max_delay=(d_max + 0.5) * dt)
        device_delay = d_min * dt
        v0, aux0 = initial_state(cfg, self.params)
        noisy = bool(self._noise_mean.any() or self._noise_sd.any())
        drawn_by_neurons = noisy and self._module is not None and self.noise_source == "culture"
        if self._module is None:
            model, common = "izhikevich", {"consistent_integration": True}
        else:
            nest_module.install(nest, self._module)  # again after every ResetKernel
            model = nest_module.MODEL
            common = {
                "tau_adapt": cfg.adaptation.tau_ms,
                "slow_share": cfg.slow_current.share,
                "tau_slow": cfg.slow_current.tau_ms,
            }
            if drawn_by_neurons:  # izhikevich_neuvision draws the culture's noise itself
                common["noise_interval"] = round(cfg.noise.interval_ms / dt)
        common.update(V_th=IZH_V_PEAK_MV, V_min=V_FLOOR_MV)
        nodes = nest.Create(model, n, params=common)
        per_neuron = {"a": self.params[0], "b": self.params[1], "c": self.params[2]}
        per_neuron.update(d=self.params[3], V_m=v0, U_m=aux0[0])
        if self._module is not None and cfg.adaptation.enabled:
            per_neuron["adapt_increment"] = self._adapt_increment
        if drawn_by_neurons:  # each neuron's generator as seeded, its population's mean, s.d.
            per_neuron.update(noise_mean=self._noise_mean, noise_sd=self._noise_sd)
            for j in range(4):
                per_neuron[f"noise_s{j}"] = self._noise_state0[j]
        if cfg.stdp.enabled:
            per_neuron["tau_minus"] = np.full(n, cfg.stdp.tau_minus_ms)
        keys = list(per_neuron)
        rows = zip(*(np.asarray(per_neuron[k]).tolist() for k in keys), strict=True)  # ints stay
        set_each(nodes, [dict(zip(keys, row, strict=True)) for row in rows])
        first = int(nodes[0].global_id)
        pre = syn.pre().astype(np.int64)
        for model, idx, spec in self._synapse_groups(pre):
            if idx.size == 0:
                continue
            nest.Connect(
                pre[idx] + first,
                syn.post[idx].astype(np.int64) + first,
                "one_to_one",
                {"synapse_model": model, "delay": steps[idx] * dt, **spec},
            )
        self._noise = None
        n_device = 0
        if noisy and not drawn_by_neurons:
            if self.noise_source == "culture":
                self._noise = _NoiseReplay(
                    nest,
                    nodes,
                    self._noise_state0,
                    self._noise_mean,
                    self._noise_sd,
                    round(cfg.noise.interval_ms / dt),
                    d_min,
                    dt,
                )
                n_device += n
            else:
                n_device += self._noise_generators(nodes, device_delay)
        recorder = nest.Create("spike_recorder", params={"time_in_steps": True})
        nest.Connect(nodes, recorder, syn_spec={"delay": device_delay})
        n_device += n
        self._device_connections = n_device
        self._n_local = len(self._local(nodes))
        self._nodes = nodes
        self._first_id = first
        self._recorder = recorder
        self.step = 0
        self._pending = _Pending.empty()
        self._i_e = np.zeros(n)  # each neuron's I_e as set in NEST (its pulses' current)
        self._i_e_on = np.zeros(0, dtype=np.int64)  # the neurons whose I_e is not 0
        self._dirty = False
        # The first Prepare sorts the connections (seconds at 10^5 neurons): done here, so
        # that the first step of a run does not pay for it.
        nest.Prepare()
        nest.Cleanup()

    def _noise_generators(self, nodes, delay_ms: float) -> int:
        """One noise_generator per population (``noise_source = "nest"``); connections."""
        inhibitory = self.layout.cell_type != EXCITATORY
        made = 0
        for flag in (False, True):
            members = np.flatnonzero(inhibitory == flag)
            mean, sd = self.cfg.noise.of_population(flag)
            if members.size == 0 or (mean == 0 and sd == 0):
                continue
            gen = self.nest.Create(
                "noise_generator",
                params={"mean": mean, "std": sd, "dt": self.cfg.noise.interval_ms},
            )
            self.nest.Connect(gen, nodes[members], syn_spec={"delay": delay_ms})
            made += members.size
        return made

    def _synapse_groups(self, pre: np.ndarray):
        """(synapse model, synapse indices, parameters) of each group of synapses."""
        cfg = self.cfg
        weight = self.synapses.weight_mv
        everything = np.arange(weight.size)
        u = cfg.depression.u
        if u > 0:
            spec = {
                "weight": weight / u,  # tsodyks2 delivers x * u * weight: x * w
                "U": u,
                "u": u,
                "x": 1.0,
                "tau_rec": cfg.depression.tau_rec_ms,
                "tau_fac": 0.0,
            }
            return [("tsodyks2_synapse", everything, spec)]
        if not cfg.stdp.enabled:
            return [("static_synapse", everything, {"weight": weight})]
        st = cfg.stdp
        exc = self.layout.cell_type[pre] == EXCITATORY
        plastic = np.flatnonzero(exc)
        fixed = np.flatnonzero(~exc)
        spec = {
            "weight": np.clip(weight[plastic], 0.0, st.w_max_mv),
            "Wmax": st.w_max_mv,
            "tau_plus": st.tau_plus_ms,
            "lambda": st.a_plus_mv / st.w_max_mv,
            "alpha": st.a_minus_mv / st.a_plus_mv if st.a_plus_mv else 0.0,
            "mu_plus": 0.0,
            "mu_minus": 0.0,
        }
        groups = [("stdp_synapse", plastic, spec)]
        if fixed.size:
            groups.append(("static_synapse", fixed, {"weight": weight[fixed]}))
        return groups

    # ------------------------------------------------------------------ running
    def run(self, duration_ms: float, pulses: Pulses | None = None) -> Spikes:
        """Advance by `duration_ms` (whole steps); return the spikes in channel space.

        As `Network.run`: pulse onsets are relative to the start of this call, and the
        parts of pulses beyond its end are carried into the next calls.

        Parameters
        ----------
        duration_ms : float
            A non-negative multiple of ``dt_ms``.
        pulses : Pulses, optional
            Current pulses in channel space.

        Returns
        -------
        Spikes
            Channel spikes with absolute times, sorted by time (then channel). Neuron-level
            spikes are in `neuron_spikes`.
        """
        n_steps = steps_of(duration_ms, self._dt)
        if pulses is not None and not isinstance(pulses, Pulses):
            raise TypeError(f"pulses must be a Pulses record, got {type(pulses).__name__}")
        added = self._neuron_pulses(pulses) if pulses is not None and len(pulses) else None
        return self._call("_run", n_steps, added)

    def _neuron_pulses(self, pulses: Pulses) -> _Pending:
        """The pulses in neuron space, on steps relative to the call (checked first)."""
        n_channels = self.layout.n if self.mea is None else self.mea.n_electrodes
        top = int(pulses.channel.max())
        if top >= n_channels:
            raise PulseError(f"pulses.channel {top} out of range (network has {n_channels})")
        n = len(pulses)
        times_ms = np.concatenate((pulses.onset_ms, pulses.width_ms)).astype(np.float64)
        steps = np.rint(times_ms / self._dt).astype(np.int64)
        start, end = steps[:n], steps[:n] + steps[n:]
        current = pulses.amplitude_ua.astype(np.float64) * self.cfg.stimulation.model_current_per_ua
        channel = pulses.channel.astype(np.int64)
        if self.mea is None:
            return _Pending(channel, current, start, end)
        lo, hi = self.mea.stim_indptr[channel], self.mea.stim_indptr[channel + 1]
        counts = hi - lo
        idx = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi, strict=True)])
        neuron = self.mea.stim_neuron[idx.astype(np.int64)]
        return _Pending(neuron, *(np.repeat(x, counts) for x in (current, start, end)))

    def _run(self, n_steps: int, added: _Pending | None) -> Spikes:
        nest = self.nest
        k0 = self.step
        k1 = k0 + n_steps
        if added is not None:
            self._pending = self._pending.plus(
                _Pending(added.neuron, added.current, added.start + k0, added.end + k0)
            )
        self._pending = self._pending.alive_after(k0)
        pend = self._pending
        edges = [[k0, k1], pend.start, pend.end]
        if self._noise is not None:
            self._noise.load(k0, k1)
            edges.append(np.arange(1, self._noise.first + 1) * self._noise.m)  # early windows
        edges = np.concatenate(edges)
        edges = np.unique(edges[(edges >= k0) & (edges <= k1)])
        self._dirty = True
        if n_steps:
            nest.Prepare()
            try:
                for a, b in zip(edges[:-1], edges[1:], strict=True):
                    self._set_currents(int(a))
                    nest.Run(float(b - a) * self._dt)
                events = self._recorder.get("events")
            finally:
                nest.Cleanup()
            set_each(self._recorder, [{"n_events": 0}])  # emptied: only outside Prepare
            neuron = np.asarray(events["senders"], dtype=np.int64) - self._first_id
            step = np.asarray(events["times"], dtype=np.int64)  # stamps: step index + 1
        else:
            neuron = step = np.zeros(0, dtype=np.int64)
        self.step = k1
        if self.comm is not None:
            parts = self.comm.gather((neuron, step), root=0)
            if self.rank != 0:
                return Spikes.concat([])
            neuron = np.concatenate([p[0] for p in parts])
            step = np.concatenate([p[1] for p in parts])
        order = np.lexsort((neuron, step))  # by time, then neuron (as sim_network)
        neuron, step = neuron[order], step[order]
        t_ms = step.astype(np.float64) * self._dt
        self._neuron_spikes = Spikes(neuron.astype(np.uint32), t_ms)
        if self.mea is None:
            return self._neuron_spikes
        return on_electrodes(self.mea, neuron, t_ms)

    def _set_currents(self, k: int) -> None:
        """Set I_e of every neuron whose current from step k on differs from what it has:
        its pulses, and in the first windows after a build its noise (`_NoiseReplay`)."""
        pend = self._pending
        on = (pend.start <= k) & (k < pend.end)
        noise = self._noise
        if noise is not None and k < noise.first * noise.m:
            touched = np.arange(self.layout.n)
            current = noise.early[k // noise.m].astype(np.float64)
        elif noise is not None and k == noise.first * noise.m:
            touched = np.arange(self.layout.n)  # the early noise off
            current = np.zeros(touched.size)
        else:
            touched = np.union1d(pend.neuron, self._i_e_on)
            current = np.zeros(touched.size)
        np.add.at(current, np.searchsorted(touched, pend.neuron[on]), pend.current[on])
        changed = current != self._i_e[touched]
        if changed.any():
            idx = touched[changed]
            values = current[changed]
            set_each(self._nodes[idx], [{"I_e": float(v)} for v in values])
            self._i_e[idx] = values
            self._i_e_on = np.flatnonzero(self._i_e)

    def _local(self, nodes):
        """The nodes of this rank."""
        if self.comm is None:
            return nodes
        with warnings.catch_warnings():  # "inherently unsafe" for collective calls; get is not
            warnings.simplefilter("ignore", UserWarning)
            return self.nest.GetLocalNodeCollection(nodes)

    def potentials(self) -> np.ndarray:
        """A snapshot of the membrane potentials (float32[n], mV)."""
        return self._call("_potentials")

    def _potentials(self) -> np.ndarray | None:
        local = self._local(self._nodes)
        ids = np.asarray(local.global_id, dtype=np.int64).reshape(-1) - self._first_id
        v = np.asarray(local.get("V_m"), dtype=np.float32).reshape(-1)
        if self.comm is not None:
            parts = self.comm.gather((ids, v), root=0)
            if self.rank != 0:
                return None
            ids = np.concatenate([p[0] for p in parts])
            v = np.concatenate([p[1] for p in parts])
        out = np.empty(self.layout.n, dtype=np.float32)
        out[ids] = v
        return out

    def weights(self) -> np.ndarray:
        """The synapses' weights now (mV), in ``synapses`` order (one process only).

        Returns
        -------
        float64[m]
            Changed by STDP; a depressing synapse's weight is the one a fully recovered
            synapse delivers.
        """
        if self.comm is not None:
            raise NotImplementedError("weights() reads the synapses of one process only")
        return self._call("_weights")

    def _weights(self) -> np.ndarray:
        got = self.nest.GetConnections(self._nodes, self._nodes).get(["source", "target", "weight"])
        n = self.layout.n
        key = (np.asarray(got["source"], np.int64) - self._first_id) * n + (
            np.asarray(got["target"], np.int64) - self._first_id
        )
        w = np.asarray(got["weight"], np.float64) * (self.cfg.depression.u or 1.0)
        syn = self.synapses
        want = syn.pre().astype(np.int64) * n + syn.post.astype(np.int64)
        order = np.argsort(key)
        return w[order][np.searchsorted(key[order], want)]

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, np.ndarray]:
        """The state as built, the only one NEST can return to (`set_state` takes it).

        Returns
        -------
        dict
            ``{"step": 0}``.

        Raises
        ------
        NotImplementedError
            After the network has run: NEST cannot save a running network's state.
        """
        if self.step != 0:
            raise NotImplementedError(
                "NEST cannot save a running network's state; only the state as built "
                "(get_state() before the first run) can be restored"
            )
        return {"step": np.array(0, dtype=np.int64)}

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        """Back to the network as built (the state from `get_state`): rebuilt in NEST,
        unless it has not run since it was built or a `reset` rebuilt it since.

        Raises
        ------
        NotImplementedError
            ``state`` is not the state as built.
        """
        if int(state["step"]) != 0 or len(state) != 1:
            raise NotImplementedError("NEST can only return to the network as built (step 0)")
        self._call("_rebuild_if_run")

    def _rebuild_if_run(self) -> None:
        if self._dirty:
            self._build()

    def reset(self, background: bool = False) -> None:
        """Rebuild the network as built (a fresh NEST kernel at time 0).

        Parameters
        ----------
        background : bool
            Return at once: the rebuild goes on in the NEST thread, and every later call
            waits for it. The culture endpoint does this when a run ends, so that the next
            run can start at once.
        """
        if not background:
            self._call("_build")
            return
        self._ready()
        self._rebuilding = nest_thread().submit(self._collective, "_build", ())

    def _ready(self) -> None:
        """Wait for a rebuild under way (raising its error); fail if retired."""
        if self._rebuilding is not None:
            future, self._rebuilding = self._rebuilding, None
            try:
                future.result()
            except Exception as exc:
                raise RuntimeError(f"rebuilding the NEST network failed: {exc}") from exc
        if _owner is not self:
            raise NestRetired(
                "another NestNetwork was built in this process since: NEST holds one "
                "network per process"
            )

    # ------------------------------------------------------------------ threads and ranks
    def _call(self, name: str, *args):
        """``self.<name>(*args)`` on the NEST thread (and, under MPI, on every rank)."""
        self._ready()
        return nest_thread().call(self._collective, name, args)

    def _collective(self, name: str, args: tuple):
        """On the NEST thread: rank 0 sends the call to the other ranks, then makes it."""
        if self.comm is not None and self.rank == 0:
            self.comm.bcast((name, args), root=0)
        return getattr(self, name)(*args)

    def follow(self) -> None:
        """On a rank other than 0: do what rank 0 does, until it calls `close`."""
        if self.comm is None or self.rank == 0:
            raise RuntimeError("follow() is for MPI ranks other than 0")
        nest_thread().call(self._follow)

    def _follow(self) -> None:
        while True:
            name, args = self.comm.bcast(None, root=0)
            if name == "_stop":
                return
            getattr(self, name)(*args)

    def close(self) -> None:
        """Release the other ranks from `follow` (MPI, rank 0): after a rebuild under way."""
        if self.comm is not None and self.rank == 0:
            self._ready()
            nest_thread().call(self.comm.bcast, ("_stop", ()), 0)
