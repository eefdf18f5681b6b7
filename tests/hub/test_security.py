"""The security profiles (``bus.security = "mtls"`` or ``"password"``): who may connect,
and who may put what.

Real Zenoh TLS on loopback, certificates and passwords made by ``neuvision certs``; the
hub's router enforces the access-control policy of :mod:`hub.security`.
"""

from __future__ import annotations

import json
import os
import queue
import threading
from pathlib import Path

import pytest
import zenoh

from hub.bus import BusError, open_session, payload_bytes, zenoh_config
from hub.certs import make_certificates, make_passwords
from hub.cli import main
from hub.config import ConfigError, load_config
from hub.protocol import (
    ControlReply,
    ControlRequest,
    Description,
    HubStatus,
    MotorCommand,
    Stimulation,
)
from hub.security import PARTICIPANTS, PASSWORDS_FILE, access_control, password_file
from tests.harness import harness, wait_for

pytest.importorskip("cryptography")


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("certs")
    make_certificates(folder, list(PARTICIPANTS), hub_hosts=["127.0.0.1"])
    make_passwords(folder, list(PARTICIPANTS))
    return folder


def _secured(bus_overrides, certs, mode: str) -> list[str]:
    return [o.replace("tcp/", "tls/") for o in bus_overrides if o.startswith("bus.")] + [
        f'bus.security="{mode}"',
        f'bus.certs_dir="{certs}"',
        "bus.connect_timeout_s=2",
    ]


@pytest.fixture
def mtls(bus_overrides, certs) -> list[str]:
    """The test's isolated bus, over mutual TLS with the experiment's certificates."""
    return _secured(bus_overrides, certs, "mtls")


@pytest.fixture
def password(bus_overrides, certs) -> list[str]:
    """The test's isolated bus, over TLS with a password per participant."""
    return _secured(bus_overrides, certs, "password")


@pytest.fixture(params=["mtls", "password"])
def secured(request, bus_overrides, certs) -> list[str]:
    """Either profile: what holds for both."""
    return _secured(bus_overrides, certs, request.param)


# ------------------------------------------------------------------ certificates


def test_certs_makes_a_ca_and_one_certificate_per_role_named_by_its_role(tmp_path):
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    assert main(["certs", str(tmp_path), "--roles", "hub,body", "--hub-hosts", "10.0.0.1,hub"]) == 0
    hub = x509.load_pem_x509_certificate((tmp_path / "hub.pem").read_bytes())
    assert hub.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == "hub"
    names = hub.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    # loopback always: the hub's own burst observer reaches it there
    assert [str(n.value) for n in names] == ["127.0.0.1", "localhost", "10.0.0.1", "hub"]
    assert (tmp_path / "body.key").stat().st_mode & 0o077 == 0  # keys: owner only
    # A participant added later is signed by the same CA.
    ca_before = (tmp_path / "ca.pem").read_bytes()
    assert main(["certs", str(tmp_path), "--roles", "observer"]) == 0
    assert (tmp_path / "ca.pem").read_bytes() == ca_before
    observer = x509.load_pem_x509_certificate((tmp_path / "observer.pem").read_bytes())
    assert observer.issuer == hub.issuer


def test_certs_passwords_gives_each_role_its_own_secret_and_the_hub_their_dictionary(tmp_path):
    assert main(["certs", str(tmp_path), "--roles", "hub,body,culture", "--passwords"]) == 0
    body = password_file(tmp_path, "body").read_text().strip()
    culture = password_file(tmp_path, "culture").read_text().strip()
    assert len(body) >= 24 and body != culture
    assert not password_file(tmp_path, "hub").exists()  # the hub shows its certificate
    dictionary = (tmp_path / PASSWORDS_FILE).read_text().splitlines()
    assert dictionary == [f"body:{body}", f"culture:{culture}"]
    for path in (password_file(tmp_path, "body"), tmp_path / PASSWORDS_FILE):
        assert path.stat().st_mode & 0o077 == 0  # secrets: owner only
    # A role added later joins the dictionary; the others keep theirs.
    assert main(["certs", str(tmp_path), "--roles", "observer", "--passwords"]) == 0
    observer = password_file(tmp_path, "observer").read_text().strip()
    assert (tmp_path / PASSWORDS_FILE).read_text().splitlines() == dictionary + [
        f"observer:{observer}"
    ]


def test_certs_refuses_a_role_that_is_not_a_participant(tmp_path, capsys):
    assert main(["certs", str(tmp_path), "--roles", "hub,robot"]) == 3
    err = capsys.readouterr().err
    assert "--roles" in err and "robot" in err and len(err.strip().splitlines()) == 1


# ------------------------------------------------------------------ configuration


def test_mtls_needs_tls_addresses_and_the_hub_as_router(certs):
    with pytest.raises(ConfigError, match=r"bus\.listen: .*tls/HOST:PORT"):
        load_config(None, ['bus.security="mtls"', 'bus.listen=["tcp/127.0.0.1:7447"]'])
    with pytest.raises(ConfigError, match=r"bus\.mode"):
        load_config(
            None,
            ['bus.security="mtls"', 'bus.listen=["tls/127.0.0.1:7447"]', 'bus.mode="peer"'],
        )


def test_a_participant_without_its_certificate_file_is_told_which_file(tmp_path, certs):
    cfg = load_config(
        None,
        ['bus.security="mtls"', 'bus.listen=["tls/127.0.0.1:7447"]', f'bus.certs_dir="{tmp_path}"'],
    )
    with pytest.raises(BusError, match=r"no ca file .*ca\.pem.* for the body"):
        zenoh_config(cfg.bus, listener=False, role="body")
    with pytest.raises(BusError, match=r"needs a role"):
        zenoh_config(cfg.bus, listener=False, role=None)


def test_the_access_policy_lets_each_role_put_only_on_its_own_keys():
    keys = load_config(None, ['bus.session="s"']).bus.keys
    acl = access_control(keys)
    assert acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    puts = {
        p["subjects"][0]: sorted(
            k
            for name in p["rules"]
            if rules[name]["flows"] == ["ingress"] and "put" in rules[name]["messages"]
            for k in rules[name]["key_exprs"]
        )
        for p in acl["policies"]
    }
    assert puts == {
        "body": ["nv/s/body/*/sensors"],
        "culture": ["nv/s/culture/*/potentials", "nv/s/culture/*/spikes"],
        "observer": ["nv/s/observer/*/reports"],  # the burst observer's, sealed by the hub
        "operator": [],
    }
    # Only the burst observer may ask for the spikes the hub keeps for it (sealed besides).
    asks = {
        p["subjects"][0]: {
            k
            for name in p["rules"]
            if "query" in rules[name]["messages"]
            for k in rules[name]["key_exprs"]
        }
        for p in acl["policies"]
    }
    spikes = "nv/s/observer/*/spikes/*"
    assert [role for role, keys in asks.items() if spikes in keys] == ["observer"]
    # Nobody may put what only the hub sends (it is the router: its puts enter by no link).
    assert not any(
        k.endswith(("/stim", "/motor", "/hub/status"))
        for r in acl["rules"]
        if r["flows"] == ["ingress"] and "put" in r["messages"]
        for k in r["key_exprs"]
    )


# ------------------------------------------------------------------ on the bus


@pytest.mark.slow  # a run's start-up under TLS
def test_no_valid_password_no_connection(tmp_path, password, certs):
    cfg = load_config(None, password)
    hub = open_session(cfg.bus, listener=True)
    try:
        # The body's name with another password.
        wrong = tmp_path / "wrong"
        wrong.mkdir()
        (wrong / "ca.pem").write_bytes((certs / "ca.pem").read_bytes())
        password_file(wrong, "body").write_text("not-the-password\n")
        other = load_config(None, password + [f'bus.certs_dir="{wrong}"'])
        with pytest.raises(BusError, match="cannot reach the hub.*refused the body's password"):
            open_session(other.bus, listener=False, role="body")
        # TLS, but no password at all.
        no_password = zenoh_config(cfg.bus, listener=False, role="observer")
        no_password.insert_json5("transport/auth/usrpwd", "{}")
        with pytest.raises(zenoh.ZError):
            zenoh.open(no_password).close()
        # No password file: the message names it, before any connection.
        (tmp_path / "ca.pem").write_bytes((certs / "ca.pem").read_bytes())
        with pytest.raises(BusError, match=r"no password in .*body\.password.* for the body"):
            zenoh_config(
                load_config(None, password + [f'bus.certs_dir="{tmp_path}"']).bus,
                listener=False,
                role="body",
            )
        # The real observer gets in, with the CA and its password: no key pair of its own.
        only = tmp_path / "observer-only"
        only.mkdir()
        for name in ("ca.pem", "observer.password"):
            (only / name).write_bytes((certs / name).read_bytes())
        open_session(
            load_config(None, password + [f'bus.certs_dir="{only}"']).bus,
            listener=False,
            role="observer",
        ).close()
    finally:
        hub.close()


def test_no_valid_certificate_no_connection(tmp_path, mtls, certs):
    cfg = load_config(None, mtls)
    hub = open_session(cfg.bus, listener=True)
    try:
        # A certificate of the right role from another CA.
        stranger = tmp_path / "stranger"
        make_certificates(stranger, ["body"], hub_hosts=["127.0.0.1"])
        for name in ("body.pem", "body.key"):
            (tmp_path / "mixed").mkdir(exist_ok=True)
            (tmp_path / "mixed" / name).write_bytes((stranger / name).read_bytes())
        (tmp_path / "mixed" / "ca.pem").write_bytes((certs / "ca.pem").read_bytes())
        other_ca = load_config(None, mtls + [f'bus.certs_dir="{tmp_path / "mixed"}"'])
        with pytest.raises(BusError, match="cannot join the hub.*refused the body.s certificate"):
            open_session(other_ca.bus, listener=False, role="body")
        # TLS, but no client certificate at all.
        no_cert = zenoh_config(cfg.bus, listener=False, role="observer")
        no_cert.insert_json5(
            "transport/link/tls",
            f'{{"root_ca_certificate": "{certs / "ca.pem"}", "enable_mtls": true}}',
        )
        with pytest.raises(zenoh.ZError):
            zenoh.open(no_cert).close()
        # Plain TCP to the TLS port.
        plain = zenoh_config(
            load_config(None, [o for o in mtls if "bus." in o]).bus, listener=False, role="observer"
        )
        port = cfg.bus.listen[0].rsplit(":", 1)[1]
        plain.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{port}"]')
        with pytest.raises(zenoh.ZError):
            zenoh.open(plain).close()
        # The real observer gets in.
        open_session(cfg.bus, listener=False, role="observer").close()
    finally:
        hub.close()


def _listening_ports(pid: int) -> set[tuple[str, int]]:
    """(protocol, port) of every listening TCP and bound UDP socket of a process."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    found = set()
    for proto in ("tcp", "tcp6", "udp", "udp6"):
        path = Path(f"/proc/net/{proto}")
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            fields = line.split()
            local, state, inode = fields[1], fields[3], fields[9]
            listening = state == "0A" if proto.startswith("tcp") else True
            if inode in inodes and listening:
                found.add((proto.rstrip("6"), int(local.rsplit(":", 1)[1], 16)))
    return found


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="no /proc/net here")
def test_a_wrong_role_reaches_no_endpoint_and_observers_only_watch(secured, tmp_path):
    out: dict = {}
    with harness(tmp_path, [], *secured, "experiment.duration_s=4", "body.params.delay_ms=5") as h:
        bus, keys = h.cfg.bus, h.cfg.bus.keys
        port = int(bus.listen[0].rsplit(":", 1)[1])

        def intrude():
            body = open_session(bus, listener=False, role="body")
            observer = open_session(bus, listener=False, role="observer")
            operator = open_session(bus, listener=False, role="operator")
            try:
                statuses: queue.SimpleQueue = queue.SimpleQueue()
                watch = observer.declare_subscriber(keys.hub_status, statuses.put)
                stim = Stimulation(
                    step=10**6, run="x", t0_s=0, t1_s=0.01, channel=[0], amplitude_ua=[1],
                    width_ms=[1], onset_ms=[0],
                )  # fmt: skip
                motor = MotorCommand(
                    step=10**6, run="x", t0_s=0, t1_s=0.01, left_mps=1, right_mps=1
                )
                for _ in range(20):
                    body.put(keys.stim("0"), stim.encode())  # the body's certificate: not its key
                    observer.put(keys.motor("0"), motor.encode())  # an observer puts nothing
                    observer.put(keys.sensors("0"), b"\x00")
                out["sent"] = 40
                # Nobody declares another role's liveliness: an observer posing as a culture.
                posing = observer.liveliness().declare_token(keys.alive("culture", "9"))
                # What the endpoints saw, asked on the intruders' own links (after their puts,
                # in order): their counters of what they dropped.
                out["counters"] = {
                    (who, role): Description.decode(payload_bytes(r.ok)).counters["dropped"]
                    for who, session in (("body", body), ("observer", observer))
                    for role in ("body", "culture")
                    for r in session.get(keys.describe(role, "0"), timeout=5)
                }
                pause = ControlRequest(cmd="pause").encode()
                out["observer_control"] = list(
                    observer.get(keys.hub_control, payload=pause, timeout=1)
                )
                if out["observer_control"]:  # the policy failed: let the run go on, to fail
                    resume = ControlRequest(cmd="resume").encode()
                    list(observer.get(keys.hub_control, payload=resume, timeout=5))
                out["operator_status"] = [
                    ControlReply.decode(payload_bytes(r.ok))
                    for r in operator.get(
                        keys.hub_control, payload=ControlRequest(cmd="status").encode(), timeout=5
                    )
                ]
                out["observer_status"] = [
                    HubStatus.decode(payload_bytes(r.ok))
                    for r in observer.get(keys.hub_status, timeout=5)
                ]
                wait_for(lambda: not statuses.empty())
                out["published_status"] = HubStatus.decode(payload_bytes(statuses.get()))
                watch.undeclare()
                posing.undeclare()
                # Only the hub's listener is open, in the hub's process and in no endpoint's.
                out["ports"] = {
                    "hub": _listening_ports(os.getpid()),
                    **{r: _listening_ports(h.pid(r)) for r in ("body", "culture")},
                }
            finally:
                for s in (body, observer, operator):
                    s.close()

        intruder = threading.Thread(target=intrude)

        def start(progress):
            if progress.step >= 20 and not intruder.is_alive() and "started" not in out:
                out["started"] = True
                intruder.start()

        result = h.run(progress=start)
        intruder.join(timeout=30)
    assert out.get("sent") == 40
    assert result.outcome == "completed" and result.steps == 400
    assert result.counts["dropped"] == {}  # the observer's sensors never reached the hub
    # Nothing of the intruders' reached an endpoint: the router dropped it.
    assert out["counters"] == {
        (w, r): {} for w in ("body", "observer") for r in ("body", "culture")
    }
    assert out["observer_control"] == []  # refused by the router: no answer, no pause
    assert [r.ok for r in out["operator_status"]] == [True]
    assert len(out["observer_status"]) == 1 and out["observer_status"][0].step > 0
    assert out["published_status"].step > 0
    assert out["ports"] == {"hub": {("tcp", port)}, "body": set(), "culture": set()}
    # The hub never saw the observer's token as a culture's liveliness.
    alive = [e.payload for e in h.record.events if e.key == "alive"]
    assert {"role": "culture", "id": "9"} not in alive and {"role": "culture", "id": "0"} in alive
    # The hub heard the operator's status request and never the observer's pause.
    commands = [e.payload["cmd"] for e in h.record.events if e.key == "control"]
    assert commands == ["status"]


@pytest.mark.bus
def test_neuvision_run_on_one_machine_keeps_the_profile_on_a_port_of_its_own(secured, tmp_path):
    trivial = [
        'body.kind="tests.endpoints:EchoBody"',
        'culture.kind="tests.endpoints:EchoCulture"',
        'coding.scheme="tests.endpoints:code_step_count"',
        'decoding.scheme="tests.endpoints:decode_step"',
    ]
    args = ["run", "--duration-s", "0.5", "--quiet", "--runs-dir", str(tmp_path / "runs")]
    for item in secured + trivial:
        args += ["--set", item]
    assert main(args) == 0
    (run_dir,) = (tmp_path / "runs").iterdir()
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert manifest["outcome"] == "completed"
    # the burst observer (its own role) asked for the spikes and had every step's
    assert manifest["counts"]["online_analysis"] == "complete"
    (listen,) = manifest["config"]["bus"]["listen"]
    assert listen.startswith("tls/127.0.0.1:")  # the free port it took is a TLS one too
