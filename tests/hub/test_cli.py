"""The command line: any bad input is one line on stderr and exit status 3, before a run
folder or a process exists."""

import errno
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

import hub.launch
from hub import stopping
from hub.cli import EXIT_CONFIG, main
from hub.protocol import SpikeBatch
from hub.record import Recorder, write_manifest
from tests.windows import RUN

CLOSED_LOOP = Path(__file__).resolve().parents[2] / "configs" / "closed_loop.toml"
PNG = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x01\x00\x00\x00\x01\x08\x02"


@pytest.fixture
def no_process(monkeypatch):
    """Fails the test if the command starts any process."""

    def popen(*args, **kwargs):
        raise AssertionError(f"a process was started: {args}")

    monkeypatch.setattr(hub.launch.subprocess, "Popen", popen)


def refused(capsys, argv: list[str]) -> str:
    """Run the CLI; check exit status 3 and a one-line message; return the message."""
    assert main(argv) == EXIT_CONFIG
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    assert len(err.splitlines()) == 1, err
    return err


def refused_run(capsys, tmp_path, config, *overrides) -> str:
    runs = tmp_path / "runs"
    argv = ["run", str(config), "--quiet", "--runs-dir", str(runs)]
    for item in overrides:
        argv += ["--set", item]
    err = refused(capsys, argv)
    assert not runs.exists(), "a run folder was made"
    return err


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("picture.png", PNG, "is not a text file"),
        ("empty.toml", b"", "is empty"),
        ("comments.toml", b"# nothing here\n", "is empty"),
        ("page.html", b"<html><body>experiment</body></html>\n", "is not valid TOML"),
        ("world.toml", b'[arena]\nshape = "circle"\nradius_m = 1.0\n', "arena is not a known key"),
    ],
)
def test_a_config_file_that_is_not_an_experiment_is_refused(
    capsys, tmp_path, no_process, name, content, message
):
    path = tmp_path / name
    path.write_bytes(content)
    err = refused_run(capsys, tmp_path, path)
    assert message in err and (name in err or "arena" in err)


def test_a_folder_or_a_missing_file_as_the_config_is_refused(capsys, tmp_path, no_process):
    assert "is a folder" in refused_run(capsys, tmp_path, tmp_path)
    assert "nope.toml not found" in refused_run(capsys, tmp_path, tmp_path / "nope.toml")


def test_a_shipped_config_named_from_another_folder_is_refused_with_where_it_is(
    capsys, tmp_path, no_process, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    err = refused_run(capsys, tmp_path, "configs/closed_loop.toml")
    assert "configs/closed_loop.toml not found (relative to the current folder" in err
    shipped = Path(__file__).resolve().parents[2] / "configs" / "closed_loop.toml"
    assert f"the project's own is {shipped}" in err


@pytest.mark.parametrize(
    "override, message",
    [
        ("loop.period_ms=1e-6", "loop.period_ms must be >= 0.1, got 1e-06"),
        ("experiment.duration_s=1e9", "experiment.duration_s = 1000000000.0 s at loop.period_ms"),
        ("loop.perod_ms=5", "loop.perod_ms is not a known key (did you mean period_ms?)"),
        ('body.params.world="nope.toml"', "body.params.world: world file"),
        ('culture.params.config="nope.toml"', "culture.params.config: culture file"),
        ("culture.params.noise.sd=-1", "culture.params.noise.sd must be >= 0, got -1.0"),
        ("culture.params.potentials_hz=-1", "culture.params.potentials_hz must be >= 0"),
        ("body.params.wheels=2", "body.params.wheels is not a known key"),
        ("body.params.arena.radius_m=0", "body.params.arena.radius_m must be a finite number > 0"),
        ('body.kind="no_such_module:Body"', "body.kind: cannot load"),
        ('coding.scheme="no_such_module:f"', "coding.scheme: cannot import"),
        ("online.burst={min_spikes=0}", "online.burst"),
        ("online.burst={bogus=1}", "online.burst.bogus is not a known key (known: min_spikes"),
        ("online.burst.window_ms=-1", "online.burst.window_ms must be > 0, got -1"),
        # a bound that follows another parameter says which
        ("decoding.params.max_speed_mps=0.01", "must be >= 0.05, got 0.01 (min_speed_mps)"),
        # an address Zenoh would refuse only once the run's folder and processes exist
        ('bus.listen=["tcp/127.0.0.1:99999"]', "bus.listen: 'tcp/127.0.0.1:99999' has no port"),
        ('bus.listen=["garbage"]', "bus.listen: 'garbage' is not an address"),
        ("bus.listen=[]", "bus.listen: at least one address"),
        ('bus.session=""', "bus.session: session name is needed"),
        # an endpoint's id is a chunk of its keys too: "" crashed the hub, "a/b" hung it
        ('body.id=""', "body.id: endpoint id is needed"),
        ("experiment.seed=18446744073709551616", "experiment.seed must be <= 18446744073709551615"),
        ('culture.id="a/b"', "culture.id: endpoint id 'a/b' may not hold /"),
        ('bus.session="lab/3"', "bus.session: session name 'lab/3' may not hold /"),
        ('bus.connect=["tcp/hub.lab"]', "bus.connect: 'tcp/hub.lab' has no host and port"),
    ],
)
def test_a_bad_value_is_named_by_its_key(capsys, tmp_path, no_process, override, message):
    assert message in refused_run(capsys, tmp_path, CLOSED_LOOP, override)


def test_an_external_endpoints_bad_parameter_is_found_before_the_run(capsys, tmp_path, no_process):
    err = refused_run(
        capsys, tmp_path, CLOSED_LOOP, 'culture.launch="external"', "culture.params.noise.sd=-1"
    )
    assert "culture.params.noise.sd must be >= 0" in err


def test_the_hub_alone_checks_the_same(capsys, tmp_path, no_process):
    runs = tmp_path / "runs"
    argv = ["hub", str(CLOSED_LOOP), "--quiet", "--runs-dir", str(runs)]
    err = refused(capsys, argv + ["--set", "body.params.seed=-1"])
    assert "body.params.seed must be >= 0" in err and not runs.exists()


@pytest.mark.parametrize(
    "address, message",
    [
        ("127.0.0.1:abc", "bus.connect: 'tcp/127.0.0.1:abc' has no port 0 to 65535"),
        ("127.0.0.1:", "'127.0.0.1:' is not an address"),
    ],
)
def test_a_bad_connect_address_is_one_line_before_anything_waits(capsys, address, message):
    assert message in refused(capsys, ["ctl", "status", "--connect", address])


def test_a_missing_run_folder_is_one_line(capsys, tmp_path):
    assert "run folder" in refused(capsys, ["analyze", str(tmp_path / "nope")])
    assert "not found" in refused(capsys, ["record-info", str(tmp_path / "nope")])
    assert "is not a run folder" in refused(capsys, ["record-info", str(tmp_path)])
    (tmp_path / "file").write_text("x")
    assert "is not a run folder" in refused(capsys, ["analyze", str(tmp_path / "file")])


def test_compare_checks_every_condition_before_running(capsys, tmp_path, no_process):
    out = tmp_path / "out"
    err = refused(
        capsys, ["compare", str(CLOSED_LOOP), str(tmp_path / "nope.toml"), "--out", str(out)]
    )
    assert "nope.toml not found" in err and not out.exists()


def test_the_installed_command_prints_no_traceback(tmp_path):
    picture = tmp_path / "picture.png"
    picture.write_bytes(PNG)
    proc = subprocess.run(
        [sys.executable, "-m", "hub.cli", "run", str(picture), "--runs-dir", str(tmp_path / "r")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == EXIT_CONFIG
    assert proc.stderr.strip().splitlines() == [
        f"neuvision: config error: config file {picture} is not a text file (binary content); "
        "expected TOML"
    ]
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("seeds", ["0", "-2"])
def test_compare_refuses_fewer_than_one_seed_before_running(capsys, tmp_path, no_process, seeds):
    out = tmp_path / "out"
    argv = ["compare", str(CLOSED_LOOP), "--seeds", seeds, "--out", str(out)]
    assert f"--seeds must be >= 1 (seeds 1..N per condition), got {seeds}" in refused(capsys, argv)
    assert not out.exists()


def test_compare_refuses_two_conditions_of_the_same_name(capsys, tmp_path, no_process):
    out = tmp_path / "out"
    err = refused(capsys, ["compare", str(CLOSED_LOOP), str(CLOSED_LOOP), "--out", str(out)])
    assert err.startswith("neuvision: conditions need distinct experiment.name values")
    assert "closed_loop" in err and not out.exists()


@pytest.fixture
def run_folder(tmp_path) -> Path:
    """A folder that commands take as a run (it holds a manifest)."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "manifest.json").write_text('{"outcome": "completed", "steps": 0}')
    (run / "record.nvrec").write_bytes(b"")  # its existence is what the commands look at first
    return run


def test_an_output_folder_that_cannot_be_made_is_named_with_the_reason(
    capsys, tmp_path, no_process, run_folder
):
    in_the_way = tmp_path / "file"
    in_the_way.write_text("not a folder")
    below = str(in_the_way / "x")
    why = f"{in_the_way} is a file, not a folder"
    cases = [
        (["run", str(CLOSED_LOOP), "--runs-dir", str(in_the_way)], "experiment.runs_dir"),
        (["run", str(CLOSED_LOOP), "--runs-dir", below], "experiment.runs_dir"),
        (["analyze", str(run_folder), "--out", below], "--out"),
        (["export", str(run_folder), "--nwb", below + ".nwb"], "--nwb"),
        (["reproduce", "--quick", "--out", below], "--out"),
        (["compare", str(CLOSED_LOOP), "--out", below], "--out"),
    ]
    for argv, option in cases:
        err = refused(capsys, argv)
        assert err.startswith(f"neuvision: {option}: cannot make folder") and why in err, err
    assert "cannot make folder /proc/nope: No such file or directory" in refused(
        capsys, ["run", str(CLOSED_LOOP), "--runs-dir", "/proc/nope"]
    )
    assert "--nwb: " in refused(capsys, ["export", str(run_folder), "--nwb", str(tmp_path)])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "run"]


@pytest.mark.parametrize(
    "args, message",
    [
        (["intan", "--command-port", "70000"], "--command-port must be a TCP port, 1 to 65535"),
        (["intan", "--spike-port", "-1"], "--spike-port must be a TCP port, 1 to 65535"),
        (["intan", "--realtime-priority", "200"], "--realtime-priority must be 0 (ordinary"),
        # another emulator's options: refused, not ignored
        (
            ["intan", "--link", "/tmp/x", "--baud", "9600"],
            "--baud, --link: not an option of the intan",
        ),
        (["khepera", "--spike-port", "5002"], "--spike-port: not an option of the khepera"),
        (["intan", "--realtime-priority", "-1"], "--realtime-priority must be 0 (ordinary"),
        (["khepera", "--link", "/nonexistent/dir/x"], "--link: /nonexistent/dir is not a folder"),
        (["khepera", "--link", "{file}"], "--link: {file} is a file, not a link"),
        (["khepera", "--link", "{dir}"], "--link: {dir} is a folder, not a link"),
        # a negative count fired on every reply (n % -1 == 0)
        (["khepera", "--garbage-every", "-1"], "--garbage-every must be >= 0, got -1"),
        (["khepera", "--drop-every", "-2"], "--drop-every must be >= 0, got -2"),
        (["khepera", "--seed", "-1"], "emulate: argument --seed: must be >= 0, got -1"),
        (["intan", "--seed", "-1"], "emulate: argument --seed: must be >= 0, got -1"),
        # argparse's own refusals: exit status 2 (a fault's) and a usage block, before
        (["khepera", "--dialect", "khepera4"], "emulate: argument --dialect: invalid choice"),
        (["khepera", "--baud", "fast"], "emulate: argument --baud: invalid int value"),
        (["khepera", "--bawd", "9600"], "emulate: unrecognized arguments: --bawd 9600"),
    ],
)
def test_an_emulators_bad_option_is_named_in_one_line(tmp_path, args, message):
    file = tmp_path / "file"
    file.write_text("not a link")
    args = [a.format(file=file, dir=tmp_path) for a in args]
    done = subprocess.run(
        [sys.executable, "-m", "hub.cli", "emulate", *args],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == EXIT_CONFIG, done.stderr
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr
    assert done.stderr.startswith("neuvision: " + message.format(file=file, dir=tmp_path))
    assert file.read_text() == "not a link"  # left as it was


@pytest.mark.parametrize(
    "manifest, record, message",
    [
        (b'{"outcome": "completed", ', b"", "manifest.json is damaged (not JSON: "),
        (b"[1, 2]", b"", "manifest.json is not a run's manifest (a JSON list, not an object)"),
        (b'{"steps": 1}', PNG, "record.nvrec is not a NeuVision record"),
    ],
)
@pytest.mark.parametrize(
    "command",
    [
        ["analyze", "{run}"],
        ["record-info", "{run}"],
        ["export", "{run}", "--nwb", "{nwb}"],
        ["dashboard", "--replay", "{run}"],
    ],
)
def test_a_damaged_run_folder_is_named_in_one_line(
    capsys, tmp_path, no_process, command, manifest, record, message
):
    run = tmp_path / "run"
    run.mkdir()
    (run / "manifest.json").write_bytes(manifest)
    (run / "record.nvrec").write_bytes(record)
    err = refused(capsys, [c.format(run=run, nwb=tmp_path / "x.nwb") for c in command])
    assert err.startswith(f"neuvision: cannot read the run in {run}: ") and message in err, err
    assert sorted(p.name for p in run.iterdir()) == ["manifest.json", "record.nvrec"]
    assert not (tmp_path / "x.nwb").exists()


def test_an_export_of_a_record_without_its_manifest_is_one_line(capsys, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "record.nvrec").write_bytes(b"")
    err = refused(capsys, ["export", str(run), "--nwb", str(tmp_path / "x.nwb")])
    assert "is not a run folder (no manifest.json): an NWB file needs the run's metadata" in err


def test_a_replays_options_are_checked_before_it_serves(capsys, tmp_path, run_folder):
    replay = ["dashboard", "--replay", str(run_folder)]
    assert "dashboard.port must be <= 65535, got 99999" in refused(
        capsys, [*replay, "--port", "99999"]
    )
    assert "--replay plays a recorded run folder; --connect and --session watch a live hub" in (
        refused(capsys, [*replay, "--connect", "localhost"])
    )


def test_analyze_help_names_where_it_writes_by_default():
    from hub.cli import build_parser
    from lab.run_analysis import ANALYSIS_DIR  # where analyze_run writes without --out

    sub = build_parser()._subparsers._group_actions[0].choices["analyze"]
    assert f"default: RUN_DIR/{ANALYSIS_DIR})" in " ".join(sub.format_help().split())


@pytest.mark.parametrize(
    "argv, message",
    [
        (["reproduce", "--seeds", "1-2", "--jobs", "0"], "argument --jobs: must be > 0, got 0"),
        (["compare", str(CLOSED_LOOP), "--jobs", "-1"], "argument --jobs: must be > 0, got -1"),
        (["ctl", "status", "--timeout-s", "-1"], "argument --timeout-s: must be > 0, got -1"),
        (["ctl", "status", "--timeout-s", "nan"], "argument --timeout-s: must be > 0, got nan"),
        (["reproduce", "--quick", "--seed", "-1"], "argument --seed: must be >= 0, got -1"),
    ],
)
def test_a_count_or_a_wait_that_is_not_positive_is_refused_in_one_line(
    capsys, tmp_path, no_process, argv, message
):
    with pytest.raises(SystemExit) as exit:
        main(argv)
    assert exit.value.code == EXIT_CONFIG  # before anything runs
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err


def test_a_reader_that_leaves_early_is_no_error(tmp_path):
    """``neuvision certs DIR | head -1``: the paths go to a pipe whose reader is gone."""
    read_end, write_end = os.pipe()
    os.close(read_end)  # gone before anything is written: every write fails (EPIPE)
    try:
        done = subprocess.run(
            [sys.executable, "-m", "hub.cli", "certs", str(tmp_path / "certs")],
            stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=60,
        )  # fmt: skip
    finally:
        os.close(write_end)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    assert any((tmp_path / "certs").iterdir())  # the work was done all the same


def test_a_missing_certificate_is_a_config_error_before_any_folder(capsys, tmp_path, no_process):
    certs = tmp_path / "certs"
    err = refused_run(
        capsys, tmp_path, CLOSED_LOOP,
        'bus.security="mtls"', f'bus.certs_dir="{certs}"', 'bus.listen=["tls/127.0.0.1:7555"]',
    )  # fmt: skip
    assert f"no ca file '{certs}/ca.pem' for the hub" in err
    assert f"neuvision certs {certs}" in err  # how to make it


def test_a_full_disk_while_analysing_is_one_line_and_leaves_no_half_written_file(
    capsys, tmp_path, monkeypatch
):
    write_manifest(tmp_path, {"outcome": "completed", "steps": 100,
                              "config": {"loop": {"period_ms": 10.0}}})  # fmt: skip
    rec = Recorder(tmp_path)
    for k in range(100):
        batch = SpikeBatch(step=k, run=RUN, t0_s=k * 0.01, t1_s=(k + 1) * 0.01)
        rec.message("rx", "nv/s/culture/0/spikes", batch.encode())
    rec.close()
    write_bytes = Path.write_bytes

    def full_disk(path, data):
        write_bytes(path, data[:10])  # some of it, then no room
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_bytes", full_disk)
    err = refused(capsys, ["analyze", str(tmp_path)])
    assert f"cannot write the analysis in {tmp_path / 'analysis'}: No space left" in err
    assert list((tmp_path / "analysis").iterdir()) == []


@pytest.fixture
def sigint_ignored():
    """SIGINT ignored, as a shell leaves it for a background job (restored after)."""
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    yield
    signal.signal(signal.SIGINT, before)


def test_ctrl_c_is_taken_again_when_the_parent_left_it_ignored(capsys, tmp_path, sigint_ignored):
    main(["record-info", str(tmp_path / "nothing")])
    handler = signal.getsignal(signal.SIGINT)
    assert handler is stopping.interrupt_while_starting
    with pytest.raises(KeyboardInterrupt):  # as Python's own handler, remembered
        handler(signal.SIGINT, None)
    assert stopping.signalled_while_starting()
    stopping.forget_start_signal()


def test_a_command_called_from_another_thread_leaves_the_signals_alone(
    capsys, tmp_path, sigint_ignored
):
    """Only the main thread may set a handler: a test's operator thread that runs
    ``neuvision ctl`` through ``main`` under a parent that ignores SIGINT got a
    ValueError."""
    statuses: list[int] = []
    thread = threading.Thread(target=lambda: statuses.append(main(["record-info", str(tmp_path)])))
    thread.start()
    thread.join(30)
    assert len(statuses) == 1  # returned, without raising
    assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN


def test_certs_in_a_participants_folder_are_refused_and_its_ca_kept(capsys, tmp_path):
    """A participant's folder holds ca.pem without the CA's key: making certificates there
    would make a new CA and replace the one every other participant trusts."""
    made = tmp_path / "made"
    assert main(["certs", str(made), "--roles", "body"]) == 0
    capsys.readouterr()
    participant = tmp_path / "participant"
    participant.mkdir()
    ca = (made / "ca.pem").read_bytes()
    (participant / "ca.pem").write_bytes(ca)
    err = refused(capsys, ["certs", str(participant), "--roles", "body"])
    assert f"{participant} holds ca.pem but not ca.key" in err and "nothing was written" in err
    assert [p.name for p in participant.iterdir()] == ["ca.pem"]
    assert (participant / "ca.pem").read_bytes() == ca


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--days", "10000000"], "--days must be 1 to 36500, got 10000000"),
        (["--days", "0"], "--days must be 1 to 36500, got 0"),
    ],
)
def test_certs_bad_options_are_one_line(capsys, tmp_path, argv, message):
    assert message in refused(capsys, ["certs", str(tmp_path / "c"), *argv])
    assert not (tmp_path / "c").exists()


def test_certs_into_a_file_is_one_line(capsys, tmp_path):
    (tmp_path / "file").write_text("x")
    assert "is not a folder" in refused(capsys, ["certs", str(tmp_path / "file")])


@pytest.mark.parametrize("command", [["endpoint", "body"], ["observe", "bursts"]])
def test_a_participant_without_its_certificate_is_refused_before_it_builds(
    capsys, tmp_path, monkeypatch, command
):
    """Started on its own machine with bus.security on and its files not there: a config
    error naming the file, before its model is built or the hub is sought."""
    import hub.launch

    def no_model(*args, **kwargs):
        raise AssertionError("the endpoint was built")

    monkeypatch.setattr(hub.launch, "make_endpoint", no_model)
    secured = ['bus.security="mtls"', f'bus.certs_dir="{tmp_path}"',
               'bus.listen=["tls/127.0.0.1:7555"]']  # fmt: skip
    argv = [*command, str(CLOSED_LOOP), *[a for s in secured for a in ("--set", s)]]
    err = refused(capsys, argv)
    assert err.startswith(f"neuvision: config error: no ca file '{tmp_path}/ca.pem' for the ")


def test_the_runs_last_line_says_what_was_dropped_or_missing():
    """A run whose coder's pulses broke the culture's limits at every step but one in
    five said only "completed ... 0 late step(s)": what was lost is said there too."""
    from hub.cli import _lost_said

    counts = {"dropped": {"coding": {"limit": 799}}, "missing": {"culture": 3}}
    assert _lost_said(counts) == (
        ", 799 coding message(s) dropped (limit), 3 culture repl(ies) missing"
    )
    assert _lost_said({"dropped": {}, "missing": {}}) == ""
    # a reply past its deadline is counted late, not missing; the loop did not use it either
    assert _lost_said({"late": {"culture": 500, "body": 0}}) == (
        ", 500 culture repl(ies) late (the policy stood in)"
    )
