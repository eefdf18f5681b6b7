"""Configuration: defaults are valid, files load, bad values are rejected naming the key."""

import dataclasses

import pytest

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
    ],
)
def test_bad_values_are_rejected_naming_the_key(data, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.").replace("[", r"\[")):
        config_from_dict(data)


def test_config_is_frozen():
    cfg = NetworkConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.dt_ms = 1.0  # type: ignore[misc]


def test_network_table_is_accepted(tmp_path):
    path = tmp_path / "exp.toml"
    path.write_text("[network]\ndt_ms = 0.5\n[network.layout]\nrows = 4\ncols = 5\n")
    cfg = load_config(path)
    assert (cfg.dt_ms, cfg.n_neurons) == (0.5, 20)
