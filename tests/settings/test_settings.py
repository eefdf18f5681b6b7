"""The one settings loader: files, extends, paths, overrides, validation by dotted key."""

from dataclasses import dataclass, field

import pytest

from settings import (
    ConfigError,
    apply_overrides,
    bounds,
    build,
    load,
    merge,
    parse_value,
    read_toml,
    to_plain,
    under,
    with_overrides,
)


@dataclass(frozen=True)
class Inner:
    rate_hz: float = field(default=1.0, metadata=bounds(gt=0, le=100))
    mode: str = field(default="a", metadata=bounds(choices=("a", "b")))
    offset: float | None = None


@dataclass(frozen=True)
class Outer:
    n: int = 3
    pair: tuple[float, float] = (0.0, 1.0)
    names: tuple[str, ...] = ()
    inner: Inner = field(default_factory=lambda: Inner(mode="b"))
    table: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.pair[0] > self.pair[1]:
            raise ConfigError(f"pair must be [low, high], got {list(self.pair)}")


def test_values_are_typed_as_toml_and_bare_words_are_strings():
    assert parse_value("5") == 5 and parse_value("2.5") == 2.5 and parse_value("true") is True
    assert parse_value("[1, 2]") == [1, 2] and parse_value("{a = 1}") == {"a": 1}
    assert parse_value('"x y"') == "x y" and parse_value("realtime") == "realtime"


def test_a_table_builds_its_dataclass_and_back():
    obj = build(Outer, {"n": 4, "pair": [1, 2], "names": "x", "inner": {"rate_hz": 5}})
    assert obj == Outer(n=4, pair=(1.0, 2.0), names=("x",), inner=Inner(rate_hz=5.0, mode="b"))
    assert build(Outer, to_plain(obj)) == obj
    assert with_overrides(obj, ["inner.offset=-1"]).inner.offset == -1.0


@pytest.mark.parametrize(
    "data, message",
    [
        ({"nam": 1}, "x.nam is not a known key (did you mean names?)"),
        ({"n": 1.5}, "x.n must be an integer, got 1.5"),
        ({"n": True}, "x.n must be an integer"),
        ({"pair": [1]}, "x.pair must be a list of 2 numbers"),
        ({"pair": [2, 1]}, "x.pair must be [low, high]"),
        ({"names": [1]}, "x.names must be a list of strings"),
        ({"inner": 3}, "x.inner must be a table"),
        ({"inner": {"rate_hz": 0}}, "x.inner.rate_hz must be > 0, got 0.0"),
        ({"inner": {"rate_hz": 1e3}}, "x.inner.rate_hz must be <= 100"),
        ({"inner": {"rate_hz": float("inf")}}, "x.inner.rate_hz must be finite"),
        ({"inner": {"mode": "c"}}, "x.inner.mode must be one of a, b"),
        ({"inner": {"offset": "no"}}, "x.inner.offset must be a number"),
        ({"table": []}, "x.table must be a table"),
    ],
)
def test_every_error_names_its_dotted_key(data, message):
    with pytest.raises(ConfigError) as err:
        build(Outer, data, "x.")
    assert message in str(err.value)


def test_an_error_placed_under_a_prefix_keeps_its_class():
    class WorldishError(ConfigError):
        pass

    moved = under("body.params.", WorldishError("arena.radius_m must be > 0"))
    assert type(moved) is WorldishError
    assert str(moved) == "body.params.arena.radius_m must be > 0"


def test_one_merge_rule_tables_merge_arrays_replace_params_follow_their_owner():
    base = {"a": {"x": 1, "y": [1, 2]}, "s": {"scheme": "m:f", "params": {"g": 1, "h": 2}}}
    assert merge(base, {"a": {"y": [3]}}) == {"a": {"x": 1, "y": [3]}, "s": base["s"]}
    same = merge(base, {"s": {"params": {"g": 5}}})
    assert same["s"] == {"scheme": "m:f", "params": {"g": 5, "h": 2}}
    other = merge(base, {"s": {"scheme": "m:other", "params": {"k": 1}}})
    assert other["s"] == {"scheme": "m:other", "params": {"k": 1}}


def test_another_scheme_without_params_has_none_another_kind_keeps_the_bases():
    base = {
        "coding": {"scheme": "m:f", "params": {"g": 1}},
        "culture": {"kind": "sim_network", "params": {"config": "c.toml"}},
    }
    over = {"coding": {"scheme": "m:other"}, "culture": {"kind": "nest"}}
    assert merge(base, over) == {
        "coding": {"scheme": "m:other"},  # g belonged to m:f
        "culture": {"kind": "nest", "params": {"config": "c.toml"}},  # a culture's, any kind's
    }
    # naming the same scheme again is no change of scheme: its params merge
    same = merge(base, {"coding": {"scheme": "m:f", "params": {"h": 2}}})
    assert same["coding"]["params"] == {"g": 1, "h": 2}


def test_a_table_naming_another_shape_is_taken_whole():
    # a circle's radius_m means nothing to a rectangle; the same shape merges as ever
    base = {"arena": {"shape": "circle", "radius_m": 0.5}, "robot": {"preset": "paper7"}}
    over = {"arena": {"shape": "rectangle", "width_m": 1.2, "height_m": 1.0}}
    assert merge(base, over) == {"arena": over["arena"], "robot": {"preset": "paper7"}}
    same = merge(base, {"arena": {"shape": "circle", "radius_m": 0.8}})
    assert same["arena"] == {"shape": "circle", "radius_m": 0.8}
    assert merge(base, {"arena": {"radius_m": 0.8}})["arena"]["shape"] == "circle"


def test_paths_are_relative_to_the_file_and_overrides_to_the_current_folder(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "base.toml").write_text('[s]\nparams = { config = "c.toml", n = 1 }\n')
    (tmp_path / "b.toml").write_text('extends = "a/base.toml"\n[s]\nparams = { n = 2 }\n')
    data = load(tmp_path / "b.toml", paths=["*.params.config"])
    assert data == {"s": {"params": {"config": str(tmp_path / "a" / "c.toml"), "n": 2}}}
    apply_overrides(data, ['s.params.config="d.toml"'], ["*.params.config"], tmp_path / "z")
    assert data["s"]["params"]["config"] == str(tmp_path / "z" / "d.toml")


def test_an_extends_cycle_and_a_bad_extends_are_refused(tmp_path):
    (tmp_path / "a.toml").write_text('extends = "a.toml"\n')
    with pytest.raises(ConfigError, match="cycle"):
        load(tmp_path / "a.toml")
    (tmp_path / "b.toml").write_text("extends = 3\n")
    with pytest.raises(ConfigError, match="extends must be a file name"):
        load(tmp_path / "b.toml")
    # a base that is not there is named with the file that names it
    (tmp_path / "c.toml").write_text('extends = "nowhere/base.toml"\n')
    with pytest.raises(ConfigError, match=r"c\.toml: extends nowhere/base\.toml: .* not found"):
        load(tmp_path / "c.toml")


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "not found"),
        (b"", "is empty"),
        (b"\x00\x01", "is not a text file"),
        (b"a = ", "is not valid TOML"),
    ],
)
def test_only_a_toml_text_file_is_read(tmp_path, content, message):
    path = tmp_path / "f.toml"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(ConfigError, match=f"world file {path} {message}"):
        read_toml(path, "world file")


def test_an_override_must_name_a_key():
    for item in ("novalue", "=3", "a..b=1"):
        with pytest.raises(ConfigError, match="must look like dotted.key=value"):
            apply_overrides({}, [item])
    with pytest.raises(ConfigError, match="override a.b.c: a.b is not a table"):
        apply_overrides({"a": {"b": 1}}, ["a.b.c=2"])
