"""Experiment files: defaults in one place, every bad key named by its dotted path."""

import pytest

from hub.config import ConfigError, ExperimentConfig, load_config


def test_no_file_gives_the_documented_defaults():
    cfg = load_config()
    assert cfg == ExperimentConfig()
    assert cfg.loop.period_ms == 10.0 and cfg.loop.mode == "lockstep"
    assert cfg.bus.scouting is False and cfg.bus.session == "default"
    assert cfg.policy.endpoint_death == "stop"
    assert cfg.n_steps == 1000


def test_a_file_and_overrides_are_merged_over_the_defaults(tmp_path):
    path = tmp_path / "exp.toml"
    path.write_text(
        '[experiment]\nname = "x"\nduration_s = 2\n[loop]\nperiod_ms = 5\n'
        '[coding]\nscheme = "m:f"\nparams = { gain = 2.0 }\n'
    )
    cfg = load_config(path, ["loop.mode=realtime", "coding.params.gain=3"])
    assert cfg.experiment.name == "x" and cfg.n_steps == 400
    assert cfg.loop.period_ms == 5.0 and cfg.loop.mode == "realtime"
    assert cfg.coding.scheme == "m:f" and cfg.coding.params == {"gain": 3}
    assert cfg.decoding.scheme == "hub.schemes:stopped"  # untouched default
    assert cfg.source == str(path)


@pytest.mark.parametrize(
    "override, message",
    [
        ("loop.period_ms=-5", "loop.period_ms must be > 0, got -5.0"),
        ("loop.perod_ms=5", "loop.perod_ms is not a known key (did you mean period_ms?)"),
        ("lop.period_ms=5", "lop is not a known key (did you mean loop?)"),
        ('loop.mode="fast"', "loop.mode must be one of lockstep, realtime"),
        ('experiment.seed="one"', "experiment.seed must be an integer"),
        ("experiment.seed=-1", "experiment.seed must be >= 0"),
        ("bus.scouting=1", "bus.scouting must be true or false"),
        ('bus.session="a/b"', "bus.session"),
        ("bus.listen=[1]", "bus.listen must be a list of strings"),
        ('coding.scheme="nocolon"', "coding.scheme must name a callable as module:function"),
        ('body.launch="maybe"', "body.launch must be one of local, external"),
        ("loop=3", "loop must be a table"),
        ("record.flush_s=2", "record.flush_s must be <= 1.0"),
        ("loop.period_ms=nan", "loop.period_ms must be finite"),
        ("loop.cpus=1", "loop.cpus must be a list of CPU numbers (>= 0), got 1"),
        ("body.cpus=[-1]", "body.cpus must be a list of CPU numbers (>= 0)"),
        ("culture.cpus=[0, 0]", "culture.cpus names a CPU twice"),
    ],
)
def test_bad_keys_are_named_with_the_reason(override, message):
    with pytest.raises(ConfigError) as err:
        load_config(None, [override])
    assert message in str(err.value)


def test_a_missing_or_broken_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[loop\nperiod_ms = 1")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(bad)


def test_the_config_is_recorded_as_plain_data():
    d = load_config(None, ["loop.period_ms=2", "culture.cpus=[1, 0]"]).to_dict()
    assert d["loop"]["period_ms"] == 2.0
    assert d["loop"]["cpus"] == [] and d["culture"]["cpus"] == [1, 0]
    assert d["bus"]["listen"] == ["tcp/127.0.0.1:7447"]


def test_a_file_can_extend_another_and_params_tables_replace(tmp_path):
    (tmp_path / "base.toml").write_text(
        '[experiment]\nname = "base"\nseed = 4\n'
        '[coding]\nscheme = "a:b"\nparams = { gain = 2.0, width_ms = 1.0 }\n'
    )
    (tmp_path / "child.toml").write_text(
        'extends = "base.toml"\n[experiment]\nname = "child"\n'
        '[coding]\nscheme = "c:d"\nparams = { rate = 1.0 }\n'
    )
    cfg = load_config(tmp_path / "child.toml")
    assert cfg.experiment.name == "child" and cfg.experiment.seed == 4
    assert cfg.coding.scheme == "c:d" and cfg.coding.params == {"rate": 1.0}


def test_an_extends_cycle_is_an_error(tmp_path):
    (tmp_path / "a.toml").write_text('extends = "b.toml"\n')
    (tmp_path / "b.toml").write_text('extends = "a.toml"\n')
    with pytest.raises(ConfigError, match="cycle"):
        load_config(tmp_path / "a.toml")
