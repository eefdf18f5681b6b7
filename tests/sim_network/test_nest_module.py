"""Building NeuVision's NEST module (sim_network/nest_module.py): once per source version
into the cache, and a clear error naming what is missing when it cannot be built. The model
itself is tested in test_nest_backend.py."""

from __future__ import annotations

import pytest

from hub.config import ConfigError, load_config
from sim_network import nest_backend as nb
from sim_network import nest_module
from sim_network.endpoint import NestEndpoint

needs_nest = pytest.mark.skipif(
    not nb.nest_available(), reason=f"NEST is not installed: {nb.INSTALL_HINT}"
)


def fake_compiler(tmp_path, stderr: str):
    """A compiler that fails as g++ fails without the boost headers."""
    path = tmp_path / "failing-g++"
    path.write_text(f"#!/bin/sh\necho '{stderr}' >&2\nexit 1\n")
    path.chmod(0o755)
    return path


@needs_nest
def test_a_failed_build_names_what_the_compiler_said_and_what_to_install(tmp_path, monkeypatch):
    monkeypatch.setenv("NEUVISION_CACHE_DIR", str(tmp_path / "cache"))
    missing = "dictionary.h:39:10: fatal error: boost/type_index.hpp: No such file or directory"
    monkeypatch.setenv("CXX", str(fake_compiler(tmp_path, missing)))
    with pytest.raises(nest_module.NestModuleError) as info:
        nest_module.module_path()
    assert missing in str(info.value) and "apt-get install g++ libboost-dev" in str(info.value)
    assert not list((tmp_path / "cache").rglob("*.so"))  # nothing half-built left to load


@needs_nest
def test_no_compiler_is_named_as_such(tmp_path, monkeypatch):
    monkeypatch.setenv("CXX", str(tmp_path / "no-such-compiler"))
    with pytest.raises(nest_module.NestModuleError, match=r"\$CXX = .* not found"):
        nest_module.module_path()


@needs_nest
def test_the_nest_culture_that_needs_the_module_is_a_config_error_before_anything_starts(
    tmp_path, monkeypatch
):
    monkeypatch.setenv("NEUVISION_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("CXX", str(fake_compiler(tmp_path, "fatal error: ltdl.h: No such file")))
    cfg = load_config("configs/closed_loop.toml", ['culture.kind="nest"'])  # the default culture
    with pytest.raises(ConfigError, match=r"culture.kind = 'nest'.*NeuVision's NEST module"):
        cfg.resolved()
    local = 'culture.params.config="configs/culture_1024_local.toml"'  # NEST's own izhikevich
    load_config("configs/closed_loop.toml", ['culture.kind="nest"', local]).resolved()


@needs_nest
def test_an_external_nest_culture_is_checked_where_it_runs_not_by_the_hub(tmp_path, monkeypatch):
    # the hub's machine need not build the module of a culture that runs elsewhere; the
    # machine that runs it refuses, before building anything, if it cannot build it
    monkeypatch.setenv("NEUVISION_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("CXX", str(fake_compiler(tmp_path, "fatal error: ltdl.h: No such file")))
    overrides = ['culture.kind="nest"', 'culture.launch="external"']
    cfg = load_config("configs/closed_loop.toml", overrides).resolved()  # the hub's check
    with pytest.raises(ConfigError, match=r"NeuVision's NEST module.*ltdl.h"):
        NestEndpoint.from_config(cfg.culture, cfg)  # the culture's own machine


@pytest.mark.slow  # builds the NEST module
@needs_nest
def test_it_is_built_once_and_then_taken_from_the_cache():
    try:
        first = nest_module.module_path()  # built here, or by an earlier test or run
    except nest_module.NestModuleError as exc:
        pytest.skip(str(exc))
    built_at = first.stat().st_mtime_ns
    assert first.is_file() and first.parent.parent == nest_module.cache_dir()
    assert nest_module.module_path() == first and first.stat().st_mtime_ns == built_at
