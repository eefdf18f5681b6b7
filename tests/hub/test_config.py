"""Experiment files: defaults in one place, every bad key named by its dotted path."""

from pathlib import Path

import pytest

from hub.config import ConfigError, ExperimentConfig, load_config
from hub.launch import resolve_endpoints
from sim_network import NetworkConfig


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
        ("loop.period_ms=-5", "loop.period_ms must be >= 0.1, got -5.0"),
        ("loop.period_ms=1e-6", "loop.period_ms must be >= 0.1, got 1e-06"),
        ("experiment.duration_s=1e6", "is 100,000,000 steps; a run takes 1 to 10,000,000"),
        ("experiment.duration_s=0.001", "is 0 steps"),
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
        # the [analysis] table's keys, checked as the config loads
        ("analysis.bursts.min_spikes=1", "analysis.bursts.min_spikes must be an integer >= 2"),
        ("analysis.bursts.min_spkes=4", "analysis.bursts.min_spkes is not a known key"),
        ("analysis.bogus=1", "analysis.bogus is not a known key"),
        ("analysis.psth_bin_ms=0", "analysis.psth_bin_ms must be > 0, got 0.0"),
        ("analysis.network_bursts.min_fraction=2", "analysis.network_bursts.min_fraction"),
        ("analysis=3", "analysis must be a table"),
    ],
)
def test_bad_keys_are_named_with_the_reason(override, message):
    with pytest.raises(ConfigError) as err:
        load_config(None, [override])
    assert message in str(err.value)


def test_a_missing_or_broken_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
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


def test_a_path_in_a_file_named_from_the_current_folder_is_recorded_absolute(tmp_path, monkeypatch):
    # the manifest recorded bus.certs_dir as "lab/certs": from any other folder, no CA
    (tmp_path / "lab").mkdir()
    (tmp_path / "lab" / "exp.toml").write_text('[bus]\ncerts_dir = "certs"\n')
    monkeypatch.chdir(tmp_path)
    cfg = load_config("lab/exp.toml")
    assert cfg.bus.certs_dir == str(tmp_path / "lab" / "certs")


@pytest.mark.parametrize(
    "content, message",
    [
        (b"", "is empty"),
        (b"# only a comment\n", "is empty"),
        (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "is not a text file"),
        (b"\xff\xfe not utf-8", "is not a text file"),
        (b"<html><body>hello</body></html>", "is not valid TOML"),
    ],
)
def test_a_file_that_is_not_a_toml_experiment_is_refused_naming_it(tmp_path, content, message):
    path = tmp_path / "exp.toml"
    path.write_bytes(content)
    with pytest.raises(ConfigError, match=message) as err:
        load_config(path)
    assert str(path) in str(err.value)


def test_a_folder_is_not_a_config_file(tmp_path):
    with pytest.raises(ConfigError, match="is a folder"):
        load_config(tmp_path)


def test_paths_in_a_file_are_relative_to_that_file(tmp_path, monkeypatch):
    (tmp_path / "lab" / "worlds").mkdir(parents=True)
    (tmp_path / "lab" / "base.toml").write_text(
        '[body]\nparams = { world = "worlds/w.toml" }\n'
        '[culture]\nparams = { config = "../cultures/c.toml", seed = 3 }\n'
    )
    (tmp_path / "exp").mkdir()
    (tmp_path / "exp" / "exp.toml").write_text(
        'extends = "../lab/base.toml"\n[experiment]\nruns_dir = "out"\n'
        "[culture.params]\nnoise = { sd = 2.0 }\n"
    )
    monkeypatch.chdir(tmp_path / "exp")
    cfg = load_config(tmp_path / "exp" / "exp.toml", ['body.params.robot_file="r.toml"'])
    assert cfg.body.params["world"] == str(tmp_path / "lab" / "worlds" / "w.toml")
    # the extending file's params merge into the base's (same kind) ...
    assert cfg.culture.params == {
        "config": str(tmp_path / "cultures" / "c.toml"),
        "seed": 3,
        "noise": {"sd": 2.0},
    }
    # ... a path given on the command line is taken from the current folder, and the run
    # folder (output) too
    assert cfg.body.params["robot_file"] == str(tmp_path / "exp" / "r.toml")
    assert cfg.experiment.runs_dir == "out"


def test_an_extending_file_naming_another_kind_replaces_its_params(tmp_path):
    (tmp_path / "base.toml").write_text('[body]\nkind = "sim_robot"\nparams = { seed = 2 }\n')
    (tmp_path / "child.toml").write_text(
        'extends = "base.toml"\n[body]\nkind = "my.module:Body"\nparams = { port = 4 }\n'
    )
    assert load_config(tmp_path / "child.toml").body.params == {"port": 4}


def test_an_experiment_extending_the_closed_loop_with_another_scheme_drops_its_params(tmp_path):
    configs = Path(__file__).resolve().parents[2] / "configs"
    blind = tmp_path / "blind.toml"
    blind.write_text(
        f'extends = "{configs / "closed_loop.toml"}"\n[experiment]\nname = "blind"\n'
        '[coding]\nscheme = "hub.schemes:no_stimulation"\n'
    )
    cfg = load_config(blind)
    assert cfg.coding.scheme == "hub.schemes:no_stimulation" and cfg.coding.params == {}
    assert cfg.decoding.params["centre_tau_s"] == 5.0  # the same decoder: its params stay
    assert cfg.culture.params == {"config": str(configs / "culture_1024.toml")}


# ------------------------------------------------------- culture and world, from the experiment

CLOSED_LOOP = Path(__file__).resolve().parents[2] / "configs" / "closed_loop.toml"


def test_the_culture_and_the_world_are_set_from_the_experiment_and_recorded_whole(
    tmp_path, monkeypatch
):
    monkeypatch.chdir(tmp_path)  # anywhere: the experiment's paths are relative to it
    cfg = load_config(
        CLOSED_LOOP, ["culture.params.noise.sd=2.0", "body.params.arena.radius_m=0.8"]
    )
    run = cfg.resolved()
    culture, world = run.culture.params["config"], run.body.params["world"]
    assert culture["noise"]["sd"] == 2.0 and culture["layout"]["rows"] == 32
    assert run.culture.params["seed"] == cfg.experiment.seed
    assert world["arena"] == {"shape": "circle", "radius_m": 0.8}
    assert len(world["obstacles"]) == 3 and world["robot"]["preset"] == "paper7"
    # what the manifest records is the contents, enough to run again without the files
    recorded = run.to_dict()
    assert recorded["culture"]["params"]["config"]["noise"]["sd"] == 2.0
    assert recorded["body"]["params"]["world"]["arena"]["radius_m"] == 0.8
    assert resolve_endpoints(run) == run


@pytest.mark.parametrize(
    "override, message",
    [
        ("culture.params.noise.sd=-1", "culture.params.noise.sd must be >= 0, got -1.0"),
        (
            "culture.params.nois.sd=1",
            "culture.params.nois is not a known key (did you mean noise?)",
        ),
        # the endpoint's own keys are known beside the culture's, and a near miss is named
        ("culture.params.sede=3", "culture.params.sede is not a known key (did you mean seed?)"),
        ("culture.params.potential_hz=3", "(did you mean potentials_hz?); known: config, seed"),
        ("culture.params.seed=-3", "culture.params.seed must be >= 0"),
        ("culture.params.potentials_hz=1e3", "culture.params.potentials_hz must be <= 100"),
        ('culture.params.config="nope.toml"', "culture.params.config: culture file"),
        (
            "loop.period_ms=10.05",
            "loop.period_ms (10.05) must be a whole multiple of culture.params.dt_ms",
        ),
        (  # within 1e-6 of a multiple it passed, and the culture died at step 2
            "loop.period_ms=10.000001",
            "loop.period_ms (10.000001) must be a whole multiple of culture.params.dt_ms",
        ),
        ("body.params.arena.radius_m=0", "body.params.arena.radius_m must be a finite number > 0"),
        ('body.params.obstacles=[{shape="blob"}]', r"body.params.obstacles[0].shape must be one"),
        ("body.params.wheels=2", "body.params.wheels is not a known key"),
        ('body.params.world="nope.toml"', "body.params.world: world file"),
        ("body.params.world=3", "body.params.world must be a world file or table"),
    ],
)
def test_culture_and_world_errors_name_the_experiments_key(override, message):
    with pytest.raises(ConfigError) as err:
        resolve_endpoints(load_config(CLOSED_LOOP, [override]))
    assert message in str(err.value)


def test_the_default_culture_and_world_need_no_file(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    run = resolve_endpoints(load_config(None, ["culture.params.layout.rows=4"]))
    assert run.culture.params["config"]["layout"]["rows"] == 4
    assert run.culture.params["config"]["noise"]["sd"] == NetworkConfig().noise.sd
    assert run.body.params["world"]["name"] == "paper"


def test_a_world_or_culture_table_stands_for_its_file():
    run = load_config(
        None,
        [
            'body.params.world={name = "w", arena = {radius_m = 1.0}, robot = {preset = "paper7"}}',
            "culture.params.config={layout = {rows = 2, cols = 3}}",
        ],
    ).resolved()
    assert run.body.params["world"]["arena"]["radius_m"] == 1.0
    assert run.culture.params["config"]["layout"] == {
        "rows": 2,
        "cols": 3,
        "spacing_um": 50.0,
        "inhibitory_fraction": 0.2,
    }


# ------------------------------------------------------- [analysis] and the run folder's name


def test_an_analysis_table_is_accepted_checked_and_recorded(tmp_path):
    path = tmp_path / "exp.toml"
    path.write_text("[analysis]\nbursts = { min_spikes = 4 }\npsth_bin_ms = 2.5\n")
    cfg = load_config(path, ["analysis.network_bursts.min_fraction=0.5"])
    recorded = cfg.to_dict()["analysis"]
    assert recorded == {
        "bursts": {"min_spikes": 4},
        "psth_bin_ms": 2.5,
        "network_bursts": {"min_fraction": 0.5},
    }
    assert load_config().to_dict()["analysis"] == {}  # absent: the paper's definitions


@pytest.mark.parametrize("name", ["closed_loop", "run-2", "A.b_c", "_x"])
def test_a_plain_experiment_name_is_a_folder_name(name):
    assert load_config(None, [f'experiment.name="{name}"']).experiment.name == name


@pytest.mark.parametrize(
    "name", ["", "a/b", "../../escape", "..", ".hidden", "a\\\\b", "a b", "a..b", "x" * 101]
)
def test_a_name_that_is_not_one_safe_folder_name_is_refused(name):
    with pytest.raises(ConfigError, match=r"^experiment\.name must be 1 to 100 of ASCII letters"):
        load_config(None, [f'experiment.name="{name}"'])
