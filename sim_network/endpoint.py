"""Serves a simulated culture on the bus: stimulation in, spikes out.

A thin shell around :class:`sim_network.Network` (``culture.kind = "sim_network"``) or the
same culture on NEST, :class:`sim_network.nest_backend.NestNetwork` (``kind = "nest"``,
:class:`NestEndpoint`); the model lives in the library.
Parameters (``[culture.params]``): ``config`` (a culture file, relative to the experiment
file, or a culture table; default: the default culture, ``sim_network.config``'s
defaults), any key of a culture file overriding the culture's (``noise.sd``,
``layout.rows``...), ``seed`` (default the experiment's seed) and ``potentials_hz`` (rate
of membrane snapshots on ``culture/<id>/potentials``; 0, the default, for none).
"""

from __future__ import annotations

import dataclasses
import signal

import numpy as np

import settings
from hub.config import ConfigError, EndpointSection, ExperimentConfig, check_value
from hub.endpoint import Endpoint, RunRefused
from hub.protocol import Description, Potentials, RunStart, SpikeBatch, StepWindow, Stimulation
from sim_network import Network, PulseError, Pulses, nest_backend, nest_module
from sim_network.config import (
    NetworkConfig,
    config_from_dict,
    config_to_dict,
    read_config_data,
    whole_multiple,
)

# What the simulated culture takes (contract v2 limits; a real rig's are far lower): the
# paper's pulses are 10 ms of up to 150 uA, at most one per channel per 10 ms step.
MAX_AMPLITUDE_UA = 1000.0
MAX_WIDTH_MS = 100.0
MAX_PULSE_HZ = 200.0


class NetworkEndpoint(Endpoint):
    """A simulated culture advanced one hub period per step.

    Parameters
    ----------
    network : Network
        The culture, as built (its state then is what every run starts from).
    id : str
        Which culture this is on the bus.
    potentials_hz : float
        Rate of membrane-potential snapshots published for observers (0: none).
    """

    role, kind = "culture", "sim_network"
    #: ``culture.params`` keys of the endpoint itself, beside the culture's own
    #: (:class:`~sim_network.config.NetworkConfig`'s: ``noise``, ``layout``...)
    PARAMS = ("config", "seed", "potentials_hz")

    def __init__(self, network: Network, id: str = "0", potentials_hz: float = 0.0):
        super().__init__(id)
        self.net = network
        self.potentials_hz = potentials_hz
        self.potentials_every = 0
        self.period_ms = 0.0  # the run's, from its RunStart
        self._initial = network.get_state()

    @classmethod
    def check_config(cls, section: EndpointSection, cfg: ExperimentConfig) -> dict:
        """Check ``[culture.params]`` without building the network; return them resolved.

        ``config`` is a culture file or a culture table (as resolved params hold it); any
        other culture key (``noise``, ``layout``, ...) overrides the culture's.

        Parameters
        ----------
        section : EndpointSection
            The ``[culture]`` section; its ``params`` are checked.
        cfg : ExperimentConfig
            The whole experiment: the default seed, and the loop period, which must be a
            whole multiple of the culture's ``dt_ms``.

        Returns
        -------
        dict
            ``config`` (the culture's every value: the file's, or the defaults, with the
            overrides in place), ``seed`` and ``potentials_hz``: what the run uses, as the
            manifest records it.

        Raises
        ------
        ConfigError
            Naming ``culture.params.<key>`` (``culture.params.noise.sd must be >= 0``), or
            ``loop.period_ms`` when it is not a whole multiple of ``dt_ms``.
        """
        params = dict(section.params)
        settings.check_known(
            params, [*cls.PARAMS, *settings.known_keys(NetworkConfig)], "culture.params."
        )
        culture = params.pop("config", {})
        seed = check_value(
            "culture.params.seed", int, params.pop("seed", cfg.experiment.seed), ge=0
        )
        potentials_hz = check_value(
            "culture.params.potentials_hz", float, params.pop("potentials_hz", 0.0), ge=0, le=100
        )
        if isinstance(culture, str):
            try:
                culture = read_config_data(culture)
            except ConfigError as exc:
                raise ConfigError(f"culture.params.config: {exc}") from None
        elif not isinstance(culture, dict):
            raise ConfigError(
                f"culture.params.config must be a culture file or table, got {culture!r}"
            )
        network = config_from_dict(settings.merge(culture, params), prefix="culture.params.")
        if not whole_multiple(cfg.loop.period_ms, network.dt_ms):
            raise ConfigError(
                f"loop.period_ms ({cfg.loop.period_ms}) must be a whole multiple of "
                f"culture.params.dt_ms ({network.dt_ms})"
            )
        return {"config": config_to_dict(network), "seed": seed, "potentials_hz": potentials_hz}

    @classmethod
    def from_config(cls, section: EndpointSection, cfg: ExperimentConfig) -> NetworkEndpoint:
        params = cls.check_config(section, cfg)
        network = Network(config_from_dict(params["config"]), seed=params["seed"])
        return cls(network, section.id, params["potentials_hz"])

    def describe(self) -> Description:
        ch = self.net.channels
        return Description(
            role="culture",
            id=self.id,
            kind=self.kind,
            channel=ch.channel,
            x_um=ch.x_um,
            y_um=ch.y_um,
            cell_type=ch.cell_type,
            max_amplitude_ua=MAX_AMPLITUDE_UA,
            max_width_ms=MAX_WIDTH_MS,
            max_pulse_hz=MAX_PULSE_HZ,
        )

    def warm_up(self) -> None:
        """The kernels compiled (:meth:`Network.warm_up`: the culture's state unchanged)."""
        self.net.warm_up()

    def start_run(self, run: RunStart) -> None:
        """Back to the culture as built, stepped by the run's period."""
        dt_ms = self.net.cfg.dt_ms
        if not whole_multiple(run.period_ms, dt_ms):
            raise RunRefused(
                f"period_ms {run.period_ms} is not a whole multiple of the culture's dt_ms {dt_ms}"
            )
        self.net.set_state(self._initial)
        self.period_ms = run.period_ms
        hz = self.potentials_hz
        self.potentials_every = max(1, round(1e3 / (hz * run.period_ms))) if hz else 0

    def step(self, s: Stimulation, window: StepWindow) -> SpikeBatch:
        t0_ms = window.t0_s * 1e3
        dt_ms = self.net.cfg.dt_ms
        skipped = round((t0_ms - self.net.t_ms) / dt_ms)  # whole time steps (not float noise)
        if skipped > 0:  # steps the hub skipped: the culture lived on, unstimulated
            self.net.run(skipped * dt_ms)
        pulses = Pulses(s.channel, s.amplitude_ua, s.width_ms, s.onset_ms) if s.n_pulses else None
        try:
            spikes = self.net.run(self.period_ms, pulses)
        except PulseError as exc:  # refused whole, before any time passed; the step goes on
            self._drop("refused", f"stimulation of step {s.step}: {exc}")
            spikes = self.net.run(self.period_ms)
        if self.potentials_every and s.step % self.potentials_every == 0:
            self.publish_telemetry(
                self.keys.potentials(self.id),
                Potentials(step=s.step, t_s=self.net.t_ms / 1e3, v_mv=self.net.potentials()),
            )
        return SpikeBatch(
            **window.stamp,
            channel=spikes.channel,
            t_ms=(spikes.t_ms - t0_ms).astype(np.float32),
        )


class NestEndpoint(NetworkEndpoint):
    """The same culture simulated by NEST (``culture.kind = "nest"``).

    Takes the parameters of the simulated culture (``config``, culture keys, ``seed``,
    ``potentials_hz``), ``threads`` (NEST's threads in this process, default 1) and
    ``noise_source`` (``"culture"``, the culture's own noise, default; or ``"nest"``,
    NEST's noise_generator: faster at scale, other statistics, docs/nest.md); replies
    what `NetworkEndpoint` replies, with ``kind = "nest"`` in its description. A culture
    feature NEST cannot express is refused by name before anything starts
    (:func:`sim_network.nest_backend.refusals`). A run starts from the network as built:
    when a run ends, the network is rebuilt in NEST in the background for the next one.

    Under ``mpirun`` (a NEST built with MPI) every rank builds its share of the network;
    rank 0 serves on the bus and the other ranks follow it (:meth:`serve`).
    """

    kind = "nest"
    PARAMS = (*NetworkEndpoint.PARAMS, "threads", "noise_source")

    @classmethod
    def check_config(cls, section: EndpointSection, cfg: ExperimentConfig) -> dict:
        """The simulated culture's parameters checked (`NetworkEndpoint.check_config`),
        ``threads``, the features NEST cannot express, and, for a culture launched here, NEST
        present and NeuVision's NEST module built where the culture needs it
        (`sim_network.nest_module`; an external culture is checked by `from_config` on the
        machine that runs it).

        Returns
        -------
        dict
            ``config``, ``seed``, ``potentials_hz``, ``threads`` and ``noise_source``.

        Raises
        ------
        ConfigError
            Naming ``culture.params.<key>``, or saying how to install NEST or what the
            module's build needs.
        """
        params = dict(section.params)
        threads = check_value("culture.params.threads", int, params.pop("threads", 1), ge=1)
        noise_source = params.pop("noise_source", "culture")
        if noise_source not in nest_backend.NOISE_SOURCES:
            raise ConfigError(
                f"culture.params.noise_source must be one of {nest_backend.NOISE_SOURCES}, "
                f"got {noise_source!r}"
            )
        resolved = super().check_config(dataclasses.replace(section, params=params), cfg)
        culture = config_from_dict(resolved["config"])
        nest_backend.check_expressible(culture, "culture.params.")
        if section.launch == "local":  # an external culture is checked where it runs
            cls._check_installed(culture)
        return {**resolved, "threads": threads, "noise_source": noise_source}

    @staticmethod
    def _check_installed(culture) -> None:
        """NEST present and, where the culture needs it, NeuVision's NEST module built
        (once, cached after), or a `ConfigError` saying what to install."""
        if not nest_backend.nest_available():
            raise ConfigError(
                f"culture.kind = 'nest' needs NEST, which is not installed here: "
                f"{nest_backend.INSTALL_HINT}"
            )
        if nest_backend.needs_module(culture):
            try:
                nest_module.module_path()
            except nest_module.NestModuleError as exc:
                raise ConfigError(
                    "culture.kind = 'nest': this culture's adaptation or slow current needs "
                    f"NeuVision's NEST module: {exc}"
                ) from None

    @classmethod
    def from_config(cls, section: EndpointSection, cfg: ExperimentConfig) -> NestEndpoint:
        params = cls.check_config(section, cfg)
        culture = config_from_dict(params["config"])
        if section.launch != "local":  # checked by check_config where launched here
            cls._check_installed(culture)
        try:
            network = nest_backend.NestNetwork(
                culture,
                seed=params["seed"],
                threads=params["threads"],
                noise_source=params["noise_source"],
            )
        except nest_backend.MpiMismatch as exc:
            raise ConfigError(f"culture.kind = 'nest': {exc}") from None
        return cls(network, section.id, params["potentials_hz"])

    def warm_up(self) -> None:
        """Nothing: the network was prepared once when built (NEST sorts its connections
        then), and a run here would cost a rebuild to undo."""

    def end_run(self) -> None:
        """The run is over: rebuild the network as built, in the background."""
        super().end_run()
        self.net.reset(background=True)

    def close(self) -> None:
        """Release the other MPI ranks (a rebuild under way in one process is left to die
        with it)."""
        if self.net.comm is not None:
            self.net.close()

    def serve(self, bus, **kwargs) -> int:
        """Serve on the bus (rank 0); on any other MPI rank, follow rank 0 until it stops.

        A following rank ignores SIGINT and SIGTERM (``mpirun`` passes them to every rank):
        rank 0 stops serving, then releases the others, and each exits 0.
        """
        if self.net.rank != 0:
            if kwargs.get("install_signals", True):
                for sig in (signal.SIGINT, signal.SIGTERM):
                    signal.signal(sig, signal.SIG_IGN)
            self.net.follow()
            return 0
        return super().serve(bus, **kwargs)
