"""A hub that `neuvision run` starts on a port of its own is found by its session from
another terminal of the same machine: `neuvision ctl` and `neuvision dashboard` need no
address (hub/local_hubs.py)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from hub import local_hubs
from hub.record import read_run
from tests.conftest import TEST_ENDPOINTS


@pytest.fixture
def hub_files(tmp_path, monkeypatch):
    monkeypatch.setenv(local_hubs.FOLDER_ENV, str(tmp_path / "hubs"))
    return tmp_path / "hubs"


def test_a_hub_is_found_by_its_session_while_it_runs_and_not_after(hub_files, tmp_path):
    assert local_hubs.find("s1") is None
    with local_hubs.announced("s1", ["tcp/127.0.0.1:5000"], tmp_path / "run") as path:
        found = local_hubs.find("s1")
        assert found.locators == ("tcp/127.0.0.1:5000",)
        assert found.run_dir == str(tmp_path / "run")
        assert local_hubs.find("s2") is None  # another session
        assert path.parent == hub_files
    assert local_hubs.find("s1") is None
    assert list(hub_files.iterdir()) == []


def test_the_folder_is_private_to_the_user(hub_files):
    assert local_hubs.folder().stat().st_mode & 0o077 == 0


def test_a_folder_others_may_write_in_is_not_trusted(hub_files, tmp_path):
    hub_files.mkdir(mode=0o777)
    hub_files.chmod(0o777)
    with pytest.raises(PermissionError, match="not a folder of this user's alone"):
        local_hubs.folder()
    with local_hubs.announced("s1", ["tcp/127.0.0.1:5000"], tmp_path) as path:
        assert path is None  # the hub runs unannounced
        assert local_hubs.find("s1") is None


def test_a_file_left_by_a_process_that_ended_is_not_a_hub_and_is_removed(hub_files, tmp_path):
    ended = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                           capture_output=True, text=True, check=True)  # fmt: skip
    with local_hubs.announced("s1", ["tcp/127.0.0.1:5000"], tmp_path) as path:
        record = json.loads(path.read_text())
        left = path.with_name(path.name.replace(".json", "-left.json"))
        left.write_text(json.dumps(record | {"pid": int(ended.stdout)}))
        assert local_hubs.running("s1") == [local_hubs.find("s1")]  # only the live one
        assert not left.exists()


def test_two_hubs_of_one_session_are_named_and_neither_is_guessed(hub_files, tmp_path):
    with (
        local_hubs.announced("s1", ["tcp/127.0.0.1:5000"], tmp_path / "a"),
        local_hubs.announced("s1", ["tcp/127.0.0.1:6000"], tmp_path / "b"),
    ):
        with pytest.raises(local_hubs.AmbiguousSession) as refused:
            local_hubs.find("s1")
    message = str(refused.value)
    assert "2 hubs on this machine run session 's1'" in message
    assert "tcp/127.0.0.1:5000" in message and "tcp/127.0.0.1:6000" in message
    assert "give --connect" in message


def test_neuvision_ctl_reaches_a_running_hub_by_its_session_alone(tmp_path, bus_overrides):
    session = json.loads(bus_overrides[0].split("=", 1)[1])
    sets = [*TEST_ENDPOINTS, *bus_overrides, "loop.mode='realtime'"]
    run = subprocess.Popen(
        [sys.executable, "-m", "hub.cli", "run", "--quiet", "--runs-dir", str(tmp_path),
         "--duration-s", "300", *(a for s in sets for a in ("--set", s))],
        stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    ctl = [sys.executable, "-m", "hub.cli", "ctl", "--session", session, "--timeout-s", "30"]
    try:
        for line in run.stderr:  # the hub says where it listens, and then it is announced
            if "the hub listens on" in line:
                break
        status = subprocess.run([*ctl[:4], "status", *ctl[4:]], capture_output=True, text=True)
        stop = subprocess.run([*ctl[:4], "stop", *ctl[4:]], capture_output=True, text=True)
        rest = run.stderr.read()
        run.wait(timeout=60)
    finally:
        if run.poll() is None:
            run.kill()
    assert status.returncode == 0, status.stderr
    assert f"the hub of session {session!r} on this machine listens on tcp/127.0.0.1:" in (
        status.stderr
    )
    assert json.loads(status.stdout)["ok"] is True
    assert stop.returncode == 0, stop.stderr
    assert run.returncode == 0, rest
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    assert read_run(run_dir).manifest["reason"] == "stopped by control"
    assert local_hubs.find(session) is None  # gone with its hub


def test_neuvision_ctl_with_no_address_and_no_hub_here_says_where_it_looked(hub_files, capsys):
    from hub.cli import EXIT_FAULT, main

    code = main(["ctl", "status", "--session", "nobody-here", "--timeout-s", "0.5"])
    err = capsys.readouterr().err
    assert code == EXIT_FAULT
    assert "no hub on this machine (neuvision run or hub) runs session 'nobody-here'" in err
    assert "for a hub elsewhere give --connect HOST[:PORT]" in err


def test_a_hub_listening_everywhere_is_found_on_loopback():
    assert local_hubs.reachable_here("tcp/0.0.0.0:7447") == "tcp/127.0.0.1:7447"
    assert local_hubs.reachable_here("tls/[::]:7447") == "tls/[::1]:7447"
    assert local_hubs.reachable_here("tcp/10.0.0.1:7447") == "tcp/10.0.0.1:7447"


def test_neuvision_ctl_reaches_a_neuvision_hub_by_its_session_alone(tmp_path, bus_overrides):
    """`neuvision hub` (endpoints started elsewhere) is announced as `run`'s hub is: ctl
    stops it by session while it waits for its endpoints."""
    from tests.harness import wait_for

    session = json.loads(bus_overrides[0].split("=", 1)[1])
    sets = [*TEST_ENDPOINTS, *bus_overrides, 'body.launch="external"',
            'culture.launch="external"', "loop.wait_timeout_s=60"]  # fmt: skip
    hub = subprocess.Popen(
        [sys.executable, "-m", "hub.cli", "hub", "--quiet", "--runs-dir", str(tmp_path),
         *(a for s in sets for a in ("--set", s))],
        stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        wait_for(lambda: local_hubs.find(session) is not None, 30)
        stop = subprocess.run(
            [sys.executable, "-m", "hub.cli", "ctl", "stop", "--session", session],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        hub.wait(timeout=60)
    finally:
        if hub.poll() is None:
            hub.kill()
    assert stop.returncode == 0, stop.stderr
    assert f"the hub of session {session!r} on this machine listens on tcp/127.0.0.1:" in (
        stop.stderr
    )
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    assert read_run(run_dir).manifest["outcome"] == "stopped"
    assert local_hubs.find(session) is None
