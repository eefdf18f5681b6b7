"""Configuration: defaults are valid, files load, bad values are rejected naming the key."""

import dataclasses

import pytest

from settings import with_overrides
from sim_network import ConfigError, NetworkConfig, config_from_dict, config_to_dict, load_config


def test_defaults_are_valid_and_round_trip():
    cfg = NetworkConfig()
    assert cfg.n_neurons == 1024
    assert config_from_dict(config_to_dict(cfg)) == cfg


def test_culture_file_loads():
    cfg = load_config("configs/culture_1024.toml")
    assert cfg.n_neurons == 1024
    assert cfg.neurons.excitatory_type == "RS"
    assert cfg.neurons.inhibitory_type == "FS"
    assert cfg.connectivity.synaptic_delay_ms == 2.0
    assert cfg.connectivity.speed_m_s == (0.1, 1.14)


@pytest.mark.parametrize(
    ("data", "key"),
    [
        ({"layout": {"rowz": 3}}, "layout.rowz"),
        ({"connectivity": {"p_c_max": 1.5}}, "connectivity.p_c_max"),
        ({"connectivity": {"weight_exc_mv": [1.0, -1.0]}}, "connectivity.weight_exc_mv"),
        ({"connectivity": {"weight_inh_mv": [0.0, 2.0]}}, "connectivity.weight_inh_mv"),
        ({"connectivity": {"speed_m_s": [0.1]}}, "connectivity.speed_m_s"),
        ({"neurons": {"model": "adex"}}, "neurons.model"),
        ({"neurons": {"excitatory_type": "XX"}}, "neurons.excitatory_type"),
        ({"layout": {"rows": "32"}}, "layout.rows"),
        ({"layout": {"spacing_um": -1.0}}, "layout.spacing_um"),
        ({"dt_ms": 2.0}, "dt_ms"),
        ({"dt_ms": 0.3}, "noise.interval_ms"),
        ({"noise": {"sd": -1.0}}, "noise.sd"),
        ({"noise": {"inhibitory_sd": -1.0}}, "noise.inhibitory_sd"),
        ({"noise": {"inhibitory_mean": "x"}}, "noise.inhibitory_mean"),
        ({"channels": "pixels"}, "channels"),
        ({"stdp": {"tau_plus_ms": 0.0}}, "stdp.tau_plus_ms"),
        ({"mea": {"pitch_um": 0.0}}, "mea.pitch_um"),
        ({"noise": 3.0}, "noise"),
        ({"adaptation": {"increment_exc_mv_per_ms": -1.0}}, "adaptation.increment_exc_mv_per_ms"),
        ({"adaptation": {"tau_ms": 0.0}}, "adaptation.tau_ms"),
        ({"slow_current": {"share": -0.5}}, "slow_current.share"),
        ({"slow_current": {"tau_ms": 0.0}}, "slow_current.tau_ms"),
        # 10^8 neurons passed every check and never came up (the hub waited out its 120 s)
        ({"layout": {"rows": 10_000, "cols": 10_000}}, "layout must hold at most 1,000,000"),
        # a noise interval off a time step's multiple by 1e-8 of it drifts
        ({"noise": {"interval_ms": 1.000000001}}, "noise.interval_ms"),
    ],
)
def test_bad_values_are_rejected_naming_the_key(data, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.").replace("[", r"\[")):
        config_from_dict(data)


@pytest.mark.parametrize("model", ["lif", "hh"])
def test_adaptation_and_the_slow_current_are_not_silently_off_for_other_models(model):
    # they act on Izhikevich neurons only; with the default culture's on, a LIF run went
    # ahead without them while its manifest listed them
    with pytest.raises(ConfigError, match="adaptation.increment_exc_mv_per_ms acts on Izh"):
        config_from_dict({"neurons": {"model": model}})
    off = {"adaptation": {"increment_exc_mv_per_ms": 0.0}, "slow_current": {"share": 0.0}}
    assert config_from_dict({"neurons": {"model": model}, **off}).neurons.model == model


def test_config_is_frozen():
    cfg = NetworkConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.dt_ms = 1.0  # type: ignore[misc]


def test_network_table_is_accepted(tmp_path):
    path = tmp_path / "exp.toml"
    path.write_text("[network]\ndt_ms = 0.5\n[network.layout]\nrows = 4\ncols = 5\n")
    cfg = load_config(path)
    assert (cfg.dt_ms, cfg.n_neurons) == (0.5, 20)


def test_the_default_culture_is_the_calibrated_culture_file():
    # one default culture: the file lists the code's defaults, with their reasons
    assert load_config("configs/culture_1024.toml") == NetworkConfig()
    assert load_config() == NetworkConfig()
    assert NetworkConfig().noise.sd == 2.5 and NetworkConfig().connectivity.d_pc_um == 150.0


def test_the_local_culture_is_the_default_without_the_issue_21_changes():
    base, local = NetworkConfig(), load_config("configs/culture_1024_local.toml")
    assert local.layout == base.layout and local.neurons == base.neurons
    assert local.noise == base.noise
    assert base.adaptation.enabled and not local.adaptation.enabled
    assert base.slow_current.share > 0 and local.slow_current.share == 0
    assert local.connectivity.d_pc_um == 100.0 and local.depression.u == 0.15


def test_overrides_are_typed_as_toml_and_validated():
    cfg = load_config(None, ["noise.sd=3.5", "connectivity.weight_exc_mv=[0, 6]"])
    assert cfg.noise.sd == 3.5 and cfg.connectivity.weight_exc_mv == (0.0, 6.0)
    assert with_overrides(cfg, ["layout.rows=4"]).n_neurons == 4 * 32
    with pytest.raises(ConfigError, match=r"noise\.sd must be >= 0"):
        with_overrides(cfg, ["noise.sd=-1"])
    with pytest.raises(ConfigError, match=r"noise\.sdd is not a known key \(did you mean sd\?\)"):
        load_config(None, ["noise.sdd=1"])


def test_a_culture_file_can_extend_another(tmp_path):
    (tmp_path / "small.toml").write_text(
        'extends = "../' + tmp_path.name + '/base.toml"\n[layout]\nrows = 4\n'
    )
    (tmp_path / "base.toml").write_text("[layout]\ncols = 5\n[noise]\nsd = 1.0\n")
    cfg = load_config(tmp_path / "small.toml")
    assert (cfg.layout.rows, cfg.layout.cols, cfg.noise.sd) == (4, 5, 1.0)
    assert cfg.noise.inhibitory_mean == NetworkConfig().noise.inhibitory_mean


def test_a_missing_or_empty_culture_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match="culture file .*nope.toml not found"):
        load_config(tmp_path / "nope.toml")
    (tmp_path / "empty.toml").write_text("")
    with pytest.raises(ConfigError, match="empty"):
        load_config(tmp_path / "empty.toml")
