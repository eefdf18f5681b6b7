"""Spiking-network simulator of a dissociated cortical culture (library; no bus code here).

>>> from sim_network import Network, load_config
>>> net = Network(load_config("configs/culture_1024.toml"), seed=1)
>>> spikes = net.run(1000.0)
"""

from sim_network.config import (
    AdaptationConfig,
    ConfigError,
    ConnectivityConfig,
    DepressionConfig,
    HhConfig,
    LayoutConfig,
    LifConfig,
    MeaConfig,
    NetworkConfig,
    NeuronConfig,
    NoiseConfig,
    SlowCurrentConfig,
    StdpConfig,
    StimulationConfig,
    config_from_dict,
    config_to_dict,
    load_config,
)
from sim_network.network import Network
from sim_network.neurons import IZHIKEVICH_TYPES
from sim_network.records import Channels, PeriodicStimulus, PulseError, Pulses, Spikes

__all__ = [
    "Channels",
    "AdaptationConfig",
    "ConfigError",
    "ConnectivityConfig",
    "DepressionConfig",
    "HhConfig",
    "IZHIKEVICH_TYPES",
    "LayoutConfig",
    "LifConfig",
    "MeaConfig",
    "Network",
    "NetworkConfig",
    "NeuronConfig",
    "NoiseConfig",
    "SlowCurrentConfig",
    "PeriodicStimulus",
    "PulseError",
    "Pulses",
    "Spikes",
    "StdpConfig",
    "StimulationConfig",
    "config_from_dict",
    "config_to_dict",
    "load_config",
]
