"""Serves a simulated culture on the bus: stimulation in, spikes out.

A thin shell around :class:`sim_network.Network`; the model lives in the library.
Parameters (``[culture.params]``): ``config`` (network file, default the
calibrated 1024-neuron culture), ``seed`` (default the experiment's seed) and
``potentials_hz`` (rate of membrane snapshots on ``culture/<id>/potentials``;
0, the default, for none).
"""

from __future__ import annotations

import numpy as np

from hub.config import ConfigError, EndpointSection, ExperimentConfig
from hub.endpoint import Endpoint
from hub.protocol import Description, Potentials, SpikeBatch, Stimulation
from sim_network import ConfigError as NetworkConfigError
from sim_network import Network, PulseError, Pulses, load_config

DEFAULT_CULTURE = "configs/culture_1024.toml"


class NetworkEndpoint(Endpoint):
    """A simulated culture advanced one hub period per step."""

    role, kind = "culture", "sim_network"

    def __init__(self, network: Network, period_ms: float, id: str = "0", potentials_hz=0.0):
        super().__init__(id)
        self.net = network
        self.period_ms = period_ms
        self.potentials_every = round(1e3 / (potentials_hz * period_ms)) if potentials_hz else 0

    @classmethod
    def from_config(cls, section: EndpointSection, cfg: ExperimentConfig) -> NetworkEndpoint:
        params = dict(section.params)
        path = params.pop("config", DEFAULT_CULTURE)
        seed = params.pop("seed", cfg.experiment.seed)
        potentials_hz = params.pop("potentials_hz", 0.0)
        if params:
            raise ConfigError(f"culture.params.{sorted(params)[0]} is not a sim_network parameter")
        if not isinstance(potentials_hz, (int, float)) or not 0 <= potentials_hz <= 100:
            raise ConfigError(
                f"culture.params.potentials_hz must be in [0, 100], got {potentials_hz!r}"
            )
        try:
            network = Network(load_config(path), seed=seed)
        except FileNotFoundError:
            raise ConfigError(f"culture.params.config: no network file {path!r}") from None
        except NetworkConfigError as exc:
            raise ConfigError(f"culture.params.config ({path}): {exc}") from None
        return cls(network, cfg.loop.period_ms, section.id, potentials_hz)

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
        )

    def warm_up(self) -> None:
        """One stimulated period on a saved state, then the state restored exactly."""
        state = self.net.get_state()
        self.net.run(self.period_ms, Pulses.single([int(self.net.channels.channel[0])], 1.0, 1.0))
        self.net.set_state(state)

    def step(self, s: Stimulation) -> SpikeBatch:
        t0_ms = s.step * self.period_ms
        if self.net.t_ms < t0_ms:  # steps the hub skipped: the culture lived on, unstimulated
            self.net.run(t0_ms - self.net.t_ms)
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
            step=s.step,
            t0_s=t0_ms / 1e3,
            t1_s=(t0_ms + self.period_ms) / 1e3,
            channel=spikes.channel,
            t_ms=(spikes.t_ms - t0_ms).astype(np.float32),
        )
