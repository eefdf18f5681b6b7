"""Parts started as docs/remote.md says, by someone who gets a detail wrong: a hub whose
address is taken, an endpoint started with other settings than its hub's. Real processes,
real Zenoh on loopback (scouting off, a random session)."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import uuid

import pytest

from hub.record import read_run
from tests.harness import wait_for
from tests.hub.test_deployment import CONFIG, EXTERNAL, neuvision, port_of, sets

pytestmark = pytest.mark.bus


def test_a_hub_whose_address_is_taken_closes_its_run_folder_as_a_fault(tmp_path, bus_overrides):
    port = int(port_of(bus_overrides))
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as taken:
        taken.bind(("127.0.0.1", port))
        taken.listen(1)
        done = subprocess.run(
            [sys.executable, "-m", "hub.cli", "hub", CONFIG, "--quiet", "--duration-s", "0.2",
             "--runs-dir", str(tmp_path), *sets([*bus_overrides, *EXTERNAL])],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
    assert done.returncode == 2, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith(f"neuvision: cannot listen on tcp/127.0.0.1:{port}")
    (run_dir,) = tmp_path.iterdir()
    m = read_run(run_dir).manifest
    # not left "running" for ever: the run ended, as a fault, and says why
    assert m["outcome"] == "fault"
    assert m["reason"].startswith(f"cannot listen on tcp/127.0.0.1:{port}")
    assert m["steps"] == 0 and m["end_utc"]


def _hub_fault_waiting(tmp_path, bus_overrides) -> str:
    """`neuvision hub` for endpoints started elsewhere, given 8 s to see them: its fault's
    line (it ends with status 2)."""
    done = subprocess.run(
        [sys.executable, "-m", "hub.cli", "hub", CONFIG, "--quiet", "--duration-s", "0.2",
         "--runs-dir", str(tmp_path / "runs"),
         *sets([*bus_overrides, *EXTERNAL, "loop.wait_timeout_s=8"])],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr[-2000:]
    return done.stderr.strip().splitlines()[-1]


def _serve(role: str, items: list[str], log) -> subprocess.Popen:
    return neuvision("endpoint", role, CONFIG, "--once", *sets(items), stderr=log)


@pytest.mark.parametrize(
    "other, named",
    [
        pytest.param(  # another world (slow: the seed's case is the same path)
            ["body.params.arena.radius_m=2.0", "body.params.obstacles=[]"],
            "it differs in body.params.world.arena.radius_m, body.params.world.obstacles",
            marks=pytest.mark.slow,
        ),
        # the culture and the arena seeded otherwise
        (["experiment.seed=7"], "it differs in body.params.seed"),
    ],
    ids=["world", "seed"],
)
def test_an_endpoint_started_with_other_settings_than_its_hub_is_refused(
    tmp_path, bus_overrides, other, named
):
    """The same experiment file on every machine is what docs/remote.md asks for; an
    endpoint that serves other settings (another world, another seed) must not run under a
    manifest that records the hub's."""
    log = open(tmp_path / "body.log", "w")
    body = _serve("body", [*bus_overrides, *other], log)
    culture = _serve("culture", bus_overrides, subprocess.DEVNULL)
    try:
        done = subprocess.run(
            [sys.executable, "-m", "hub.cli", "hub", CONFIG, "--quiet", "--duration-s", "0.2",
             "--runs-dir", str(tmp_path / "runs"), *sets([*bus_overrides, *EXTERNAL])],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert done.returncode == 2, done.stderr[-2000:]
        last = done.stderr.strip().splitlines()[-1]
        assert last.startswith("neuvision: run failed: body/0 serves other settings than")
        assert f"({named})" in last  # which settings, not only that some differ
        (run_dir,) = (tmp_path / "runs").iterdir()
        m = read_run(run_dir).manifest
        assert m["outcome"] == "fault" and m["steps"] == 0
        assert "body/0 serves other settings" in m["reason"]
    finally:
        for p in (body, culture):
            p.terminate()
            p.wait(timeout=20)
        log.close()


@pytest.mark.slow  # three processes a run
def test_endpoints_with_the_hubs_settings_record_them(tmp_path, bus_overrides):
    """The same file and the same --set items on both sides: the run goes, and the manifest
    records each endpoint's settings digest, equal to the hub's."""
    endpoints = [_serve(role, bus_overrides, subprocess.DEVNULL) for role in ("body", "culture")]
    try:
        done = subprocess.run(
            [sys.executable, "-m", "hub.cli", "hub", CONFIG, "--quiet", "--duration-s", "0.2",
             "--runs-dir", str(tmp_path), *sets([*bus_overrides, *EXTERNAL])],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr[-2000:]
        assert [p.wait(timeout=20) for p in endpoints] == [0, 0]
    finally:
        for p in endpoints:
            if p.poll() is None:
                p.kill()
    (run_dir,) = tmp_path.iterdir()
    m = json.loads((run_dir / "manifest.json").read_text())
    for role in ("body", "culture"):
        digest = m["endpoints"][role]["settings_digest"]
        assert isinstance(digest, str) and len(digest) == 64


@pytest.mark.slow  # three endpoints and a hub
def test_two_endpoints_answering_as_one_role_are_refused(tmp_path, bus_overrides):
    """A body left running in another terminal and a new one started: both took the run and
    stepped, and the hub took whichever reply came first each step (the other dropped as
    stale), under a manifest naming one of them. Now the run is refused, naming both."""
    hub = neuvision(
        "hub", CONFIG, "--quiet", "--duration-s", "0.2", "--runs-dir", str(tmp_path / "runs"),
        *sets([*bus_overrides, *EXTERNAL]), stderr=subprocess.PIPE,
    )  # fmt: skip
    logs = [open(tmp_path / f"body{n}.log", "w") for n in range(2)]
    bodies = [_serve("body", bus_overrides, log) for log in logs]
    culture = None
    try:
        for n in range(2):  # both on the bus before the culture, so before the hub describes
            wait_for(lambda n=n: "ready on session" in (tmp_path / f"body{n}.log").read_text(), 60)
        culture = _serve("culture", bus_overrides, subprocess.DEVNULL)
        _, err = hub.communicate(timeout=120)
        assert hub.returncode == 2, err[-2000:]
        last = err.strip().splitlines()[-1]
        assert "2 endpoints answer as body/0" in last, last
        for p in bodies:
            assert f"pid {p.pid}" in last
        (run_dir,) = (tmp_path / "runs").iterdir()
        m = read_run(run_dir).manifest
        assert m["outcome"] == "fault" and m["steps"] == 0
    finally:
        for p in (hub, *bodies, culture):
            if p is not None and p.poll() is None:
                p.terminate()
                p.wait(timeout=20)
        for log in logs:
            log.close()


@pytest.mark.parametrize("parent_ignores_it", [False, True])
def test_ctrl_c_while_an_endpoint_builds_its_model_is_one_line(
    tmp_path, bus_overrides, parent_ignores_it
):
    """Ctrl-C before the endpoint serves (its model or device being built, which takes
    seconds for a large culture): one line and a clean exit, not a traceback. Also when
    started with SIGINT ignored, as a shell starts a background job: it was then ignored
    until the endpoint served (a CI job in the background saw this test hang)."""
    built = tmp_path / "building"
    items = [
        *bus_overrides,
        'body.kind="tests.endpoints:SlowToBuildBody"',
        f"body.params={{built_file={json.dumps(str(built))}, build_s=60.0}}",
    ]
    command = [sys.executable, "-m", "hub.cli", "endpoint", "body", CONFIG, *sets(items)]
    if parent_ignores_it:  # exec keeps the ignored disposition
        command = ["bash", "-c", 'trap "" INT; exec "$@"', "bash", *command]
    p = subprocess.Popen(command, text=True, stderr=subprocess.PIPE)
    try:
        wait_for(built.exists, 60)
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    assert "Traceback" not in err, err[-3000:]
    assert err.strip().splitlines()[-1] == "neuvision: interrupted"
    assert p.returncode == 0  # an endpoint asked to stop exits 0 (docs/contract.md)


@pytest.mark.slow  # waits out the hub's wait
def test_an_endpoint_on_another_session_is_named_by_the_hub_waiting_for_it(tmp_path, bus_overrides):
    """An endpoint started with another --session reaches the hub's router but not its run:
    the hub waited and said only that body/0 did not appear on its session. Now it says
    where body/0 is; and the body, serving one run (--once), exits when that hub leaves,
    though it never saw it (it waited for ever)."""
    other = f"other-{uuid.uuid4().hex[:8]}"
    body_items = [i for i in bus_overrides if not i.startswith("bus.session")]
    log = open(tmp_path / "body.log", "w")
    body = neuvision(
        "endpoint", "body", CONFIG, "--session", other, "--once", *sets(body_items), stderr=log
    )
    culture = _serve("culture", bus_overrides, subprocess.DEVNULL)
    try:
        last = _hub_fault_waiting(tmp_path, bus_overrides)
        assert "body/0 did not appear on session" in last
        assert f"body/0 is on this hub's bus under session {other!r}" in last, last
        assert "culture/0" not in last.split("did not appear")[0]
        assert body.wait(timeout=60) == 1  # UNSERVED
        said = (tmp_path / "body.log").read_text()
        assert "left without starting a run with it" in said
        assert f"another session than {other!r}" in said
    finally:
        for p in (body, culture):
            p.terminate()
            p.wait(timeout=20)
        log.close()


@pytest.mark.slow  # two hubs in turn
def test_endpoints_end_the_run_of_a_killed_hub_and_serve_the_next_one(tmp_path, bus_overrides):
    """The hub killed mid-run (SIGKILL, a crash): its router goes with it, and its clients
    got no word that its liveliness had gone. The endpoints stayed busy with the dead run
    (the body stopped by its input timeout) until a new hub came, whose run they refused
    ("busy with run ..."). Now each ends the dead run on its own, and the next hub's run
    goes."""
    logs = {role: open(tmp_path / f"{role}.log", "w") for role in ("body", "culture")}
    endpoints = [
        neuvision("endpoint", role, CONFIG, *sets(bus_overrides), stderr=logs[role])
        for role in ("body", "culture")
    ]
    hub_cmd = ["hub", CONFIG, "--quiet", "--runs-dir", str(tmp_path / "runs"), "--mode",
               "realtime", *sets([*bus_overrides, *EXTERNAL])]  # fmt: skip
    logs["hub"] = open(tmp_path / "hub.log", "w")
    first = neuvision(*hub_cmd, "--duration-s", "60", stderr=logs["hub"])

    def said(role: str) -> str:
        return (tmp_path / f"{role}.log").read_text()

    try:
        # both in the run (the hub hands it to one, then the other)
        wait_for(lambda: "took run" in said("body") and "took run" in said("culture"), 60)
        first.kill()
        first.wait(timeout=20)
        (killed,) = (tmp_path / "runs").iterdir()  # its manifest says "running" for ever
        assert read_run(killed).manifest["outcome"] == "unfinished"
        wait_for(lambda: "ended: the hub went away" in said("body"), 10)
        wait_for(lambda: "ended: the hub went away" in said("culture"), 10)
        done = subprocess.run(
            [sys.executable, "-m", "hub.cli", *hub_cmd, "--duration-s", "0.5"],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr[-2000:]
    except AssertionError as exc:  # what each part said, to tell why
        tails = "".join(f"\n--- {r}.log\n{said(r)[-2000:]}" for r in ("hub", "body", "culture"))
        raise AssertionError(f"{exc}{tails}") from None
    finally:
        for p in (first, *endpoints):
            if p.poll() is None:
                p.terminate()
                p.wait(timeout=20)
        for f in logs.values():
            f.close()


@pytest.mark.parametrize(
    "given, locator",
    [
        ("10.0.0.1", "tcp/10.0.0.1:7447"),
        ("10.0.0.1:7500", "tcp/10.0.0.1:7500"),
        ("hub.lab.example", "tcp/hub.lab.example:7447"),
        ("[::1]:7500", "tcp/[::1]:7500"),
        ("[::1]", "tcp/[::1]:7447"),
        ("::1", "tcp/[::1]:7447"),
        ("fe80::1:2", "tcp/[fe80::1:2]:7447"),
        ("tls/10.0.0.1:7447", "tls/10.0.0.1:7447"),
    ],
)
def test_connect_and_listen_addresses_become_zenoh_locators(given, locator):
    """IPv6 addresses became `tcp/[::1]:7500:7447` or `tcp/::1:7447`, which Zenoh cannot
    use ("failed to lookup address information")."""
    from argparse import Namespace

    from hub.cli import _address

    assert _address(given, Namespace(config=None, set=None)) == locator


@pytest.mark.slow  # a whole run
def test_a_hub_on_ipv6_loopback_answers_ctl(tmp_path, bus_overrides):
    try:
        with socket.socket(socket.AF_INET6, socket.SOCK_STREAM) as s:
            s.bind(("::1", 0))
            port = s.getsockname()[1]
    except OSError as exc:
        pytest.skip(f"no IPv6 loopback here: {exc}")
    session = [i for i in bus_overrides if i.startswith("bus.session")]
    log = tmp_path / "hub.log"
    with open(log, "w") as err:
        hub = neuvision(
            "hub", CONFIG, "--quiet", "--listen", f"[::1]:{port}", "--runs-dir",
            str(tmp_path / "runs"), *sets([*session, *EXTERNAL, "bus.scouting=false"]),
            stderr=err,
        )  # fmt: skip
    try:
        wait_for(lambda: "waiting for body/0" in log.read_text() or hub.poll() is not None, 60)
        ctl = subprocess.run(
            [sys.executable, "-m", "hub.cli", "ctl", "stop", "--connect", f"[::1]:{port}",
             "--timeout-s", "20", *sets(session)],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert ctl.returncode == 0, ctl.stderr[-2000:]
        assert json.loads(ctl.stdout)["state"] == "stopping"
        assert hub.wait(timeout=60) == 0, log.read_text()[-2000:]
    finally:
        if hub.poll() is None:
            hub.kill()


def test_ctl_asks_again_a_router_whose_hub_is_not_answering_yet(bus_overrides):
    """`neuvision ctl` started with (or just before) its hub reached the router before the
    hub's control queryable was declared, and said "no hub answered" at once, whatever its
    --timeout-s (1 in 4 tries in a shell). Here a router answers the first query with
    nothing, as it does before the hub's queryable is there, and the second properly."""
    from hub import wire
    from hub.bus import open_session
    from hub.config import load_config
    from hub.ctl import ctl
    from hub.protocol import ControlReply

    bus = load_config(CONFIG, bus_overrides).bus
    asked = []

    def on_control(query):
        asked.append(query)
        if len(asked) > 1:
            wire.reply(query, ControlReply(ok=True, state="running").encode())
        else:
            asked[0] = None  # no answer: the query's end goes out when it is freed
            del query

    router = open_session(bus, listener=True)
    try:
        queryable = router.declare_queryable(bus.keys.hub_control, on_control)  # noqa: F841
        reply = ctl(bus, "status", timeout_s=10.0)
    finally:
        router.close()
    assert reply is not None and reply.ok and reply.state == "running"
    assert len(asked) == 2


@pytest.mark.slow  # a whole run's start-up
def test_a_burst_observer_that_cannot_start_fails_the_hub_at_once(tmp_path, bus_overrides):
    """Under mTLS the hub starts the burst observer with the observer's certificate from its
    own certs folder. One that Zenoh cannot load ended the observer at once, saying so in
    observer.log, and the hub waited out loop.wait_timeout_s (30 s) to give a generic hint.
    Now it says why as soon as the observer has ended. (A certificate missing altogether is
    refused before the run, as a config error.)"""
    from hub.certs import make_certificates

    certs = tmp_path / "certs"
    make_certificates(certs, ["hub", "observer"], hub_hosts=["127.0.0.1"])
    (certs / "observer.pem").write_text("not a certificate\n")
    port = port_of(bus_overrides)
    session = [i for i in bus_overrides if i.startswith("bus.session")]
    items = [*session, *EXTERNAL, 'bus.security="mtls"', f"bus.certs_dir={json.dumps(str(certs))}",
             f'bus.listen=["tls/127.0.0.1:{port}"]', "loop.wait_timeout_s=600",
             "bus.connect_timeout_s=2"]  # the observer, refused, gives up then  # fmt: skip
    done = subprocess.run(
        [sys.executable, "-m", "hub.cli", "hub", CONFIG, "--quiet", "--runs-dir",
         str(tmp_path / "runs"), *sets(items)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr[-2000:]
    last = done.stderr.strip().splitlines()[-1]
    assert "the burst observer that the hub started ended before the run" in last, last
    assert "observer.log" in last, last  # where the observer said why


@pytest.mark.slow  # a whole run's start-up
def test_a_hub_says_it_starts_no_endpoint(tmp_path, bus_overrides):
    """`neuvision hub CONFIG` on the paper's file (endpoints `launch = "local"`), as
    docs/dashboard.md showed it: the hub starts no endpoint and waited in silence for those
    the file says are local. It now says whom it waits for and how they are started."""
    done = subprocess.run(
        [sys.executable, "-m", "hub.cli", "hub", CONFIG, "--quiet", "--runs-dir", str(tmp_path),
         *sets([*bus_overrides, "loop.wait_timeout_s=1", "online.enabled=false"])],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2
    said = [ln for ln in done.stderr.splitlines() if "starts no endpoint" in ln]
    assert said, done.stderr
    assert "neuvision endpoint body" in said[0] and "neuvision endpoint culture" in said[0]
    assert "neuvision run" in said[0]


@pytest.mark.slow  # a whole run's start-up
def test_a_burst_observer_started_before_its_hub_says_so_and_stops_on_ctrl_c(
    tmp_path, bus_overrides
):
    """`neuvision observe bursts CONFIG --connect HOST` with no hub yet said nothing and did
    not hear Ctrl-C: it waited out bus.connect_timeout_s (30 s) and ended with status 2. As
    an endpoint does, it now says where it is trying, and stops at Ctrl-C with status 0."""
    log = tmp_path / "observer.log"
    with open(log, "w") as err:
        p = neuvision("observe", "bursts", CONFIG, *sets(bus_overrides), stderr=err)
    try:
        wait_for(lambda: "waiting for the hub at tcp/127.0.0.1:" in log.read_text(), 20)
        p.send_signal(signal.SIGINT)
        assert p.wait(timeout=10) == 0, log.read_text()
    finally:
        if p.poll() is None:
            p.kill()
    assert "cannot reach the hub" not in log.read_text()


def test_an_endpoint_says_when_its_run_is_paused_and_when_resumed(caplog):
    """The terminal of a remote endpoint said "run ... paused" and never that it went on."""
    import logging

    from hub.protocol import RunHold, RunStart
    from tests.endpoints import EchoBody

    body = EchoBody()
    run = "a" * 32
    start = RunStart(run=run, period_ms=10.0, n_steps=10, mode="realtime", start_unix_s=1.0,
                     deadline_ms=10.0, key=bytes(16))  # fmt: skip
    caplog.set_level(logging.INFO, logger="hub.endpoint")
    assert body.take_run_request(start.encode()).ok
    assert body.take_run_request(RunHold(run=run, hold=True).encode()).ok
    assert body.take_run_request(RunHold(run=run, hold=False).encode()).ok
    said = [r.getMessage() for r in caplog.records]
    assert f"body/0: run {run} paused" in said
    assert f"body/0: run {run} resumed" in said


@pytest.mark.slow  # three mTLS set-ups
@pytest.mark.parametrize("case", ["hub name", "another CA", "no hub"])
def test_an_endpoint_refused_under_mtls_says_which_side_refused(tmp_path, bus_overrides, case):
    """An endpoint that could not join a TLS hub said "or the hub refused the body's
    certificate" whatever the cause, even when the body refused the hub's (a certificate
    made for other addresses, `--hub-hosts 10.0.0.1` as in docs/remote.md, reached at
    127.0.0.1; a ca.pem of another CA). It now looks and says which, and, a certificate
    refused, at once."""
    from hub.certs import make_certificates

    certs, other = tmp_path / "certs", tmp_path / "other"
    hosts = ["10.0.0.1"] if case == "hub name" else ["127.0.0.1"]
    make_certificates(certs, ["hub", "body"], hub_hosts=hosts)
    make_certificates(other, ["body"], hub_hosts=["127.0.0.1"])
    port = port_of(bus_overrides)
    session = [i for i in bus_overrides if i.startswith("bus.session")]
    # the hub reached at an address its certificate does not name (loopback's 127.0.0.1
    # and localhost it always names)
    address = "127.0.0.2" if case == "hub name" else "127.0.0.1"
    secure = ['bus.security="mtls"', f'bus.listen=["tls/{address}:{port}"]', *session]
    hub = None
    if case != "no hub":
        hub = neuvision(
            "hub", CONFIG, "--quiet", "--runs-dir", str(tmp_path / "runs"),
            *sets([*secure, *EXTERNAL, f"bus.certs_dir={json.dumps(str(certs))}",
                   "online.enabled=false"]),
            stderr=subprocess.DEVNULL,
        )  # fmt: skip
    body_certs = other if case == "another CA" else certs
    # a certificate refused is said at once: waiting would not change it (the subprocess's
    # own 120 s timeout would end a wait of 600 s); no hub yet is waited for
    wait_s = 4 if case == "no hub" else 600
    try:
        done = subprocess.run(
            [sys.executable, "-m", "hub.cli", "endpoint", "body", CONFIG,
             *sets([*secure, f"bus.certs_dir={json.dumps(str(body_certs))}",
                    f"bus.connect_timeout_s={wait_s}"])],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
    finally:
        if hub is not None:
            hub.terminate()
            hub.wait(timeout=30)
    assert done.returncode == 2
    last = done.stderr.strip().splitlines()[-1]
    expected = {
        "hub name": "the hub's certificate is not valid for 127.0.0.2",
        "another CA": "the hub's certificate does not verify against",
        "no hub": "nothing listens at 127.0.0.1:",
    }[case]
    assert expected in last, last
    if case != "another CA":
        assert "refused the body's certificate" not in last


@pytest.mark.slow  # a hub's start-up and its wait for endpoints
def test_a_burst_observer_serving_one_run_exits_when_its_hub_leaves_without_one(
    tmp_path, bus_overrides
):
    """`neuvision observe bursts --once` waited for ever when its hub ended without giving
    it a run (here a hub that faulted waiting for endpoints that never came): it now exits,
    status 1, saying so."""
    log = tmp_path / "observer.log"
    with open(log, "w") as err:
        observer = neuvision(
            "observe", "bursts", CONFIG, "--once", *sets(bus_overrides), stderr=err
        )
    try:
        done = subprocess.run(
            [sys.executable, "-m", "hub.cli", "hub", CONFIG, "--quiet", "--duration-s", "0.2",
             "--runs-dir", str(tmp_path / "runs"),
             *sets([*bus_overrides, *EXTERNAL, 'online.launch="external"',
                    "loop.wait_timeout_s=4"])],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert done.returncode == 2, done.stderr[-2000:]  # no endpoint came
        assert observer.wait(timeout=60) == 1, log.read_text()
    finally:
        if observer.poll() is None:
            observer.kill()
    assert "left without giving it a run" in log.read_text()


@pytest.mark.slow  # a hub's wait for its endpoints
def test_an_endpoint_under_another_id_is_named_by_the_hub_waiting_for_it(tmp_path, bus_overrides):
    """A body started with body.id = "1" where the hub's file says "0": the hub said only
    that body/0 did not appear. It now says that body/1 is there."""
    log = open(tmp_path / "body.log", "w")
    body = neuvision("endpoint", "body", CONFIG, *sets([*bus_overrides, 'body.id="1"']),
                     stderr=log)  # fmt: skip
    culture = _serve("culture", bus_overrides, subprocess.DEVNULL)
    try:
        last = _hub_fault_waiting(tmp_path, bus_overrides)
        assert "body/0 did not appear on session" in last
        assert "body/1 is, not body/0 (body.id in the hub's and the endpoint's" in last, last
    finally:
        for p in (body, culture):
            p.terminate()
            p.wait(timeout=20)
        log.close()
