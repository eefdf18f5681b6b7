"""Network configuration: frozen dataclasses holding every default once, and a TOML loader.

The defaults are the project's one default culture: the 1024-neuron culture calibrated to
the paper's spontaneous activity (docs/sim_network.md); ``configs/culture_1024.toml`` lists
the same values with their reasons, and a test keeps the two equal. A culture file lists
what differs. `load_config` reads a culture file through :mod:`settings` (the project's one
loader: TOML only, ``extends``, overrides); an unknown key, a value of the wrong type or out
of range raises `ConfigError` naming the dotted key.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import settings
from settings import ConfigError
from sim_network.neurons import IZHIKEVICH_TYPES

NEURON_MODELS = ("izhikevich", "lif", "hh")
CHANNEL_KINDS = ("neurons", "mea")

#: The default culture (the paper's, as calibrated): what a run, the reproduction and the
#: MEA emulator take when given none.
DEFAULT_CULTURE_FILE = Path(__file__).resolve().parents[1] / "configs" / "culture_1024.toml"


@dataclass(frozen=True)
class LayoutConfig:
    """Neurons on a rows × cols grid, one per square cell of side `spacing_um`."""

    rows: int = 32
    cols: int = 32
    spacing_um: float = 50.0
    inhibitory_fraction: float = 0.2


@dataclass(frozen=True)
class LifConfig:
    """Leaky integrate-and-fire parameters (current in model units, R·I in mV)."""

    tau_m_ms: float = 20.0
    v_rest_mv: float = -65.0
    v_reset_mv: float = -65.0
    v_threshold_mv: float = -50.0
    resistance: float = 1.0
    refractory_ms: float = 2.0


@dataclass(frozen=True)
class HhConfig:
    """Hodgkin–Huxley (squid axon, rest near -65 mV); current in µA/cm² model units."""

    g_na: float = 120.0
    g_k: float = 36.0
    g_leak: float = 0.3
    e_na_mv: float = 50.0
    e_k_mv: float = -77.0
    e_leak_mv: float = -54.387
    c_m: float = 1.0
    substep_ms: float = 0.025


@dataclass(frozen=True)
class NeuronConfig:
    """Which neuron model, and which Izhikevich type for each population."""

    model: str = "izhikevich"
    excitatory_type: str = "RS"
    inhibitory_type: str = "FS"
    # Izhikevich (2003) heterogeneity, r ~ U(0, 1) per neuron: excitatory c += 15·h·r²,
    # d -= 6·h·r² (RS toward chattering); inhibitory a -= 0.08·h·r, b += 0.05·h·r (FS toward
    # LTS). 0 = identical cells of the named type.
    # Calibrated: RS -> CH spread (intrinsically bursting cells start network bursts) and
    # FS -> LTS spread (lower rheobase, high-rate inhibitory cells).
    heterogeneity_exc: float = 0.8
    heterogeneity_inh: float = 0.5
    lif: LifConfig = field(default_factory=LifConfig)
    hh: HhConfig = field(default_factory=HhConfig)


@dataclass(frozen=True)
class ConnectivityConfig:
    """Distance-dependent random connectivity, P = p_c_max · exp(-d / d_pc_um), d ≤ cutoff_um."""

    p_c_max: float = 1.0
    d_pc_um: float = 150.0
    cutoff_um: float = 1000.0
    weight_exc_mv: tuple[float, float] = (0.0, 11.0)
    weight_inh_mv: tuple[float, float] = (-6.0, 0.0)
    synaptic_delay_ms: float = 2.0
    speed_m_s: tuple[float, float] = (0.1, 1.14)
    allow_self: bool = False


@dataclass(frozen=True)
class DepressionConfig:
    """Short-term synaptic depression per presynaptic neuron (Tsodyks–Markram resources).

    Each spike uses a fraction `u` of the neuron's resources x (weights are scaled by x);
    x recovers to 1 with time constant `tau_rec_ms`. `u = 0` turns depression off. Not in
    the paper; calibrated on: it ends network bursts and spaces them seconds apart.
    """

    u: float = 0.08
    tau_rec_ms: float = 7500.0


@dataclass(frozen=True)
class AdaptationConfig:
    """Spike-frequency adaptation of Izhikevich neurons (ignored for the other models).

    Each neuron carries a current w (model units: mV/ms in the Izhikevich equation, the unit
    of the noise and stimulation currents) that is subtracted from its input, decays with
    `tau_ms` and grows by its population's increment at each of its spikes. Excitatory cells
    whose reset c is at least `exempt_from_reset_mv` (chattering-like) do not adapt.
    Increments of 0 turn it off. Not in the paper; in the calibrated culture, regular-spiking
    cells fire once or twice per network burst instead of bursting, so that a network burst's
    bursting neurons are the inhibitory and the chattering-like cells, about 45 % of the
    culture, as the paper's MBR / MNBR implies (docs/sim_network.md).
    """

    increment_exc_mv_per_ms: float = 40.0
    increment_inh_mv_per_ms: float = 0.0
    tau_ms: float = 25.0
    # excitatory cells whose after-spike reset c is at least this (the chattering end of the
    # RS -> CH spread of `neurons.heterogeneity_exc`) do not adapt; None: all of them adapt
    exempt_from_reset_mv: float | None = -59.0

    def increment_of(self, inhibitory: bool) -> float:
        """The increment per spike of one population."""
        return self.increment_inh_mv_per_ms if inhibitory else self.increment_exc_mv_per_ms

    @property
    def enabled(self) -> bool:
        """Whether any population adapts."""
        return self.increment_exc_mv_per_ms > 0.0 or self.increment_inh_mv_per_ms > 0.0


@dataclass(frozen=True)
class SlowCurrentConfig:
    """A slow synaptic current beside each voltage jump (Izhikevich neurons only; ignored for
    the other models).

    A jump of J mV arriving at a neuron also starts a current (share·J/τ)·exp(−t/τ) (mV/ms),
    which brings in share·J mV more over `tau_ms` (an NMDA/GABA_B-like tail of the fast,
    jump-like synapse). `share = 0` turns it off. Not in the paper; calibrated on: it holds a
    network burst's bursting neurons firing for its ~70 ms.
    """

    share: float = 0.8
    tau_ms: float = 40.0


@dataclass(frozen=True)
class NoiseConfig:
    """Random background current: each neuron draws (mean, sd) every `interval_ms`, held.

    The current process does not depend on `dt_ms` (dt must divide `interval_ms`).
    `inhibitory_mean` / `inhibitory_sd`, when given, apply to inhibitory neurons instead.
    """

    mean: float = 0.0
    sd: float = 2.5
    interval_ms: float = 1.0
    # Calibrated: inhibitory cells get a higher mean drive (the paper's MFR s.d.).
    inhibitory_mean: float | None = 2.0
    inhibitory_sd: float | None = None

    def of_population(self, inhibitory: bool) -> tuple[float, float]:
        """(mean, sd) of the noise of one population."""
        if not inhibitory:
            return self.mean, self.sd
        mean = self.mean if self.inhibitory_mean is None else self.inhibitory_mean
        sd = self.sd if self.inhibitory_sd is None else self.inhibitory_sd
        return mean, sd


@dataclass(frozen=True)
class StimulationConfig:
    """Conversion of pulse amplitude in µA to model current units (the one place of this fact)."""

    model_current_per_ua: float = 1.0


@dataclass(frozen=True)
class StdpConfig:
    """Pair-based STDP on excitatory synapses (nearest-neighbour-free trace rule)."""

    enabled: bool = False
    a_plus_mv: float = 0.05
    a_minus_mv: float = 0.055
    tau_plus_ms: float = 20.0
    tau_minus_ms: float = 20.0
    w_max_mv: float = 10.0


@dataclass(frozen=True)
class MeaConfig:
    """Virtual MEA: electrode grid centred on the culture (8 × 8 without corners by default)."""

    rows: int = 8
    cols: int = 8
    pitch_um: float = 200.0
    drop_corners: bool = True
    record_radius_um: float = 50.0
    stim_radius_um: float = 50.0


@dataclass(frozen=True)
class NetworkConfig:
    """Everything that defines a simulated culture, with the defaults in one place."""

    dt_ms: float = 0.1
    channels: str = "neurons"
    layout: LayoutConfig = field(default_factory=LayoutConfig)
    neurons: NeuronConfig = field(default_factory=NeuronConfig)
    connectivity: ConnectivityConfig = field(default_factory=ConnectivityConfig)
    depression: DepressionConfig = field(default_factory=DepressionConfig)
    adaptation: AdaptationConfig = field(default_factory=AdaptationConfig)
    slow_current: SlowCurrentConfig = field(default_factory=SlowCurrentConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    stimulation: StimulationConfig = field(default_factory=StimulationConfig)
    stdp: StdpConfig = field(default_factory=StdpConfig)
    mea: MeaConfig = field(default_factory=MeaConfig)

    def __post_init__(self) -> None:
        validate(self)

    @property
    def n_neurons(self) -> int:
        """Number of neurons (rows × cols)."""
        return self.layout.rows * self.layout.cols


#: The most neurons a culture may have: the 99,856-neuron network builds in ~5 s and ~1 GB,
#: and both grow with the count.
MAX_NEURONS = 1_000_000


def whole_multiple(value: float, step: float) -> bool:
    """Whether ``value`` is a whole multiple (>= 1) of ``step``, to float precision.

    Tight on purpose: a period that is off by even 1e-8 of a step drifts from the culture's
    clock, step after step, until the two disagree by a time step.

    Parameters
    ----------
    value, step : float
        Same unit (ms: a hub period and the culture's ``dt_ms``); ``step`` > 0.
    """
    ratio = value / step
    return round(ratio) >= 1 and abs(ratio - round(ratio)) <= 1e-9 * ratio


def _require(ok: bool, key: str, message: str, value: Any) -> None:
    if not ok:
        raise ConfigError(f"{key} {message}, got {value!r}")


def validate(cfg: NetworkConfig) -> None:
    """Check ranges and choices; raise `ConfigError` naming the dotted key."""
    _require(0.01 <= cfg.dt_ms <= 1.0, "dt_ms", "must be in [0.01, 1]", cfg.dt_ms)
    _require(
        cfg.channels in CHANNEL_KINDS, "channels", f"must be one of {CHANNEL_KINDS}", cfg.channels
    )
    lay = cfg.layout
    _require(lay.rows >= 1, "layout.rows", "must be >= 1", lay.rows)
    _require(lay.cols >= 1, "layout.cols", "must be >= 1", lay.cols)
    _require(lay.spacing_um > 0, "layout.spacing_um", "must be > 0", lay.spacing_um)
    _require(
        lay.rows * lay.cols <= MAX_NEURONS,
        "layout",
        f"must hold at most {MAX_NEURONS:,} neurons (rows x cols; the 99,856-neuron network "
        "builds in ~5 s and ~1 GB)",
        f"{lay.rows} x {lay.cols}",
    )
    _require(
        0.0 <= lay.inhibitory_fraction <= 1.0,
        "layout.inhibitory_fraction",
        "must be in [0, 1]",
        lay.inhibitory_fraction,
    )
    neu = cfg.neurons
    _require(
        neu.model in NEURON_MODELS, "neurons.model", f"must be one of {NEURON_MODELS}", neu.model
    )
    for key in ("excitatory_type", "inhibitory_type"):
        name = getattr(neu, key)
        _require(
            name in IZHIKEVICH_TYPES,
            f"neurons.{key}",
            f"must be one of {tuple(IZHIKEVICH_TYPES)}",
            name,
        )
    for key in ("heterogeneity_exc", "heterogeneity_inh"):
        h = getattr(neu, key)
        _require(0.0 <= h <= 1.0, f"neurons.{key}", "must be in [0, 1]", h)
    lif = neu.lif
    _require(lif.tau_m_ms > 0, "neurons.lif.tau_m_ms", "must be > 0", lif.tau_m_ms)
    _require(
        lif.v_threshold_mv > lif.v_reset_mv,
        "neurons.lif.v_threshold_mv",
        "must be > neurons.lif.v_reset_mv",
        lif.v_threshold_mv,
    )
    _require(lif.resistance > 0, "neurons.lif.resistance", "must be > 0", lif.resistance)
    _require(lif.refractory_ms >= 0, "neurons.lif.refractory_ms", "must be >= 0", lif.refractory_ms)
    hh = neu.hh
    _require(hh.c_m > 0, "neurons.hh.c_m", "must be > 0", hh.c_m)
    _require(
        0 < hh.substep_ms <= 0.05, "neurons.hh.substep_ms", "must be in (0, 0.05]", hh.substep_ms
    )
    for key in ("g_na", "g_k", "g_leak"):
        _require(getattr(hh, key) >= 0, f"neurons.hh.{key}", "must be >= 0", getattr(hh, key))
    con = cfg.connectivity
    _require(0.0 <= con.p_c_max <= 1.0, "connectivity.p_c_max", "must be in [0, 1]", con.p_c_max)
    _require(con.d_pc_um > 0, "connectivity.d_pc_um", "must be > 0", con.d_pc_um)
    _require(con.cutoff_um >= 0, "connectivity.cutoff_um", "must be >= 0", con.cutoff_um)
    _range_ok(con.weight_exc_mv, "connectivity.weight_exc_mv", sign=+1)
    _range_ok(con.weight_inh_mv, "connectivity.weight_inh_mv", sign=-1)
    _require(
        con.synaptic_delay_ms >= 0,
        "connectivity.synaptic_delay_ms",
        "must be >= 0",
        con.synaptic_delay_ms,
    )
    _range_ok(con.speed_m_s, "connectivity.speed_m_s", sign=+1)
    _require(con.speed_m_s[0] > 0, "connectivity.speed_m_s", "must be > 0", con.speed_m_s)
    dep = cfg.depression
    _require(0.0 <= dep.u <= 1.0, "depression.u", "must be in [0, 1]", dep.u)
    _require(dep.tau_rec_ms > 0, "depression.tau_rec_ms", "must be > 0", dep.tau_rec_ms)
    ada = cfg.adaptation
    for key in ("increment_exc_mv_per_ms", "increment_inh_mv_per_ms"):
        inc = getattr(ada, key)
        _require(inc >= 0, f"adaptation.{key}", "must be >= 0", inc)
    _require(ada.tau_ms > 0, "adaptation.tau_ms", "must be > 0", ada.tau_ms)
    slo = cfg.slow_current
    _require(slo.share >= 0, "slow_current.share", "must be >= 0", slo.share)
    _require(slo.tau_ms > 0, "slow_current.tau_ms", "must be > 0", slo.tau_ms)
    if neu.model != "izhikevich":  # they act on Izhikevich neurons only: not silently off
        for key, value in (
            ("adaptation.increment_exc_mv_per_ms", ada.increment_exc_mv_per_ms),
            ("adaptation.increment_inh_mv_per_ms", ada.increment_inh_mv_per_ms),
            ("slow_current.share", slo.share),
        ):
            _require(
                value == 0,
                key,
                f"acts on Izhikevich neurons only: set it to 0 for neurons.model {neu.model!r}",
                value,
            )
    noi = cfg.noise
    _require(noi.sd >= 0, "noise.sd", "must be >= 0", noi.sd)
    if noi.inhibitory_sd is not None:
        _require(noi.inhibitory_sd >= 0, "noise.inhibitory_sd", "must be >= 0", noi.inhibitory_sd)
    _require(noi.interval_ms > 0, "noise.interval_ms", "must be > 0", noi.interval_ms)
    _require(
        whole_multiple(noi.interval_ms, cfg.dt_ms),
        "noise.interval_ms",
        f"must be a whole multiple of dt_ms={cfg.dt_ms}",
        noi.interval_ms,
    )
    sti = cfg.stimulation
    _require(
        sti.model_current_per_ua >= 0,
        "stimulation.model_current_per_ua",
        "must be >= 0",
        sti.model_current_per_ua,
    )
    st = cfg.stdp
    for key in ("a_plus_mv", "a_minus_mv"):
        _require(getattr(st, key) >= 0, f"stdp.{key}", "must be >= 0", getattr(st, key))
    for key in ("tau_plus_ms", "tau_minus_ms", "w_max_mv"):
        _require(getattr(st, key) > 0, f"stdp.{key}", "must be > 0", getattr(st, key))
    mea = cfg.mea
    _require(mea.rows >= 1, "mea.rows", "must be >= 1", mea.rows)
    _require(mea.cols >= 1, "mea.cols", "must be >= 1", mea.cols)
    _require(mea.pitch_um > 0, "mea.pitch_um", "must be > 0", mea.pitch_um)
    _require(
        mea.record_radius_um >= 0, "mea.record_radius_um", "must be >= 0", mea.record_radius_um
    )
    _require(mea.stim_radius_um >= 0, "mea.stim_radius_um", "must be >= 0", mea.stim_radius_um)


def _range_ok(pair: tuple[float, float], key: str, sign: int) -> None:
    lo, hi = pair
    _require(lo <= hi, key, "must be [low, high] with low <= high", list(pair))
    if sign > 0:
        _require(lo >= 0, key, "must be >= 0", list(pair))
    else:
        _require(hi <= 0, key, "must be <= 0", list(pair))


def config_from_dict(data: dict, prefix: str = "") -> NetworkConfig:
    """Build a validated `NetworkConfig` from nested plain values (as read from TOML).

    Parameters
    ----------
    data : dict
        Nested plain values; absent keys keep the defaults.
    prefix : str
        Put before the dotted key in error messages (``"culture.params."``).

    Raises
    ------
    ConfigError
        An unknown key, a wrong type or a value out of range, naming ``<prefix><dotted key>``.
    """
    return settings.build(NetworkConfig, data, prefix)


def config_to_dict(cfg: NetworkConfig) -> dict:
    """Nested plain values of a config (tuples as lists), the inverse of `config_from_dict`."""
    return settings.to_plain(cfg)


def read_config_data(path: str | Path) -> dict:
    """The plain contents of a culture file (its ``extends`` applied; a top-level
    ``[network]`` table is used when present), not yet validated."""
    data = settings.load(path, "culture file")
    if isinstance(data.get("network"), dict):
        data = data["network"]
    return data


def load_config(path: str | Path | None = None, overrides: Sequence[str] = ()) -> NetworkConfig:
    """Read a culture file and apply ``dotted.key=value`` overrides (``noise.sd=3.5``).

    Parameters
    ----------
    path : path or None
        A culture TOML file; None: the default culture (this module's defaults).
    overrides : sequence of str
        Applied after the file, values typed as TOML.

    Raises
    ------
    ConfigError
        Naming the file or the dotted key.
    """
    data = read_config_data(path) if path is not None else {}
    return config_from_dict(settings.apply_overrides(data, overrides))
