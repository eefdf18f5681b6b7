"""A scheme's params are checked before the run, without the endpoints' descriptions:
the same checks the factory makes (one place each), so a bad parameter is a config error
(exit 3) before a run folder or a process exists. What needs the descriptions (more sites
than channels) is checked when the factory is called, once the endpoints described."""

from __future__ import annotations

import pytest

from hub.config import load_config
from hub.schemes import ConfigError, SchemeContext, check_scheme, load_scheme
from lab.experiment import check_hub_sections, run_experiment
from tests.schemes.descriptions import body, context, grid

BAD = [
    ("coding", "hub.coding:somatotopic", {"width_ms": 0}, "coding.params.width_ms must be > 0"),
    ("coding", "hub.coding:somatotopic", {"bogus": 1}, "coding.params.bogus is not a parameter"),
    ("coding", "hub.coding:somatotopic", {"sites_per_sensor": 0}, "sites_per_sensor must be >= 1"),
    ("coding", "hub.coding:somatotopic_inverse", {"gain_ua_per_m": -1}, "gain_ua_per_m must be"),
    ("coding", "hub.coding:somatotopic", {"min_amplitude_ua": 200}, "min_amplitude_ua must be <="),
    ("coding", "hub.coding:somatotopic", {"pulse_period_ms": 5}, "pulse_period_ms must be >="),
    ("coding", "hub.coding:rate", {"max_rate_hz": 500}, "coding.params.max_rate_hz must be <= 100"),
    ("coding", "hub.coding:rate", {"channels": [1, [2, 1]]}, "channel 1 is listed for two"),
    ("coding", "hub.schemes:no_stimulation", {"sites_per_sensor": 4}, "known: none"),
    ("decoding", "hub.decoding:center_of_activity", {"window_ms": -1}, "window_ms must be > 0"),
    (
        "decoding",
        "hub.decoding:center_of_activity",
        {"max_speed_mps": 0.01, "min_speed_mps": 0.05},
        "max_speed_mps",
    ),  # fmt: skip
    ("decoding", "hub.decoding:two_population", {"left_channels": [1]}, "right_channels is needed"),
    ("decoding", "hub.decoding:two_population", {"crossed": 1}, "crossed must be true or false"),
    ("decoding", "hub.schemes:stopped", {"gain": 1}, "decoding.params.gain is not a parameter"),
]


@pytest.mark.parametrize("section, scheme, params, message", BAD)
def test_a_bad_parameter_is_refused_before_the_endpoints_describe(section, scheme, params, message):
    with pytest.raises(ConfigError) as before:
        check_scheme(section, scheme, params, period_ms=10.0)
    assert message in str(before.value)
    # the factory, given descriptions, refuses it with the very same message
    ctx = SchemeContext(body(), grid(), params=params, period_ms=10.0, section=section)
    with pytest.raises(ConfigError) as at_start:
        load_scheme(scheme, section)(ctx)
    assert str(at_start.value) == str(before.value)


def test_good_params_pass_and_what_needs_the_culture_waits_for_it():
    check_scheme("coding", "hub.coding:somatotopic", {"sites_per_sensor": 200}, period_ms=10.0)
    with pytest.raises(ConfigError, match="needs 1400 channels, the culture offers"):
        load_scheme("hub.coding:somatotopic", "coding")(context(sites_per_sensor=200))


def test_a_scheme_without_its_own_check_is_only_imported():
    check_scheme("coding", "tests.schemes.descriptions:body", {"anything": 1}, period_ms=10.0)
    with pytest.raises(ConfigError, match="coding.scheme: cannot import 'no_such_module'"):
        check_scheme("coding", "no_such_module:f", {}, period_ms=10.0)


@pytest.mark.parametrize("name", ["closed_loop", "closed_loop_blind", "hybrid_mea"])
def test_the_shipped_experiments_pass(name):
    check_hub_sections(load_config(f"configs/{name}.toml"))


def test_a_run_with_a_bad_scheme_parameter_stops_before_its_folder_exists(tmp_path):
    runs = tmp_path / "runs"
    with pytest.raises(ConfigError, match="coding.params.width_ms must be > 0"):
        run_experiment(
            "configs/closed_loop.toml",
            ["coding.params.width_ms=0", f'experiment.runs_dir="{runs}"'],
            install_signals=False,
        )
    assert not runs.exists()
