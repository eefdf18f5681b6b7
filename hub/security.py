"""The security profile of a session: TLS links, a role per participant, access control.

With ``bus.security = "mtls"`` every link is TLS with a client certificate (Zenoh's own TLS,
mutual authentication), issued by the experiment's certificate authority (``neuvision
certs``, :mod:`hub.certs`); the certificate's common name is the participant's role. With
``bus.security = "password"`` every link is TLS too, but only the hub shows a certificate; a
participant proves its role with Zenoh's user/password authentication (user = role, password
from ``<role>.password``; the hub checks them against ``passwords``, both made by
``neuvision certs --passwords``): a lab hands out a CA and a password, not a key pair, per
machine. In either mode the hub's router admits each role's messages only on that role's own
keys (Zenoh's access control, enforced where the message enters the router): only the
culture may put ``spikes``, only the body ``sensors``; observers may subscribe, and query
descriptions and ``hub/status``, and the burst observer's keys are theirs (its reports are
sealed with a key the hub gives it, so another observer cannot forge them); only an
operator may send ``hub/control`` (pause, resume,
stop). The hub itself is the router: what it puts (``stim``, ``motor``, ``hub/status``)
enters through no link, and no link may put on those keys. Nobody but a role may declare
that role's liveliness token.

Plain data only: these functions return Zenoh configuration values; :mod:`hub.bus` puts
them into the configuration.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

from hub.protocol import Keys

#: who may take part: the hub, the two endpoint roles, observers (dashboards, recorders)
#: that only watch, and operators that may also pause, resume and stop the run
PARTICIPANTS = ("hub", "body", "culture", "observer", "operator")
SECURITY_MODES = ("none", "mtls", "password")

CA_FILE = "ca.pem"
#: the hub's dictionary of every participant's password (``role:password`` lines)
PASSWORDS_FILE = "passwords"


def password_file(certs_dir: str | Path, role: str) -> Path:
    """The file that holds one participant's password (``bus.security = "password"``).

    Parameters
    ----------
    certs_dir : str or Path
        The folder of the experiment's certificates and passwords (``bus.certs_dir``).
    role : str
        The participant.
    """
    return Path(certs_dir) / f"{role}.password"


def certificate_files(certs_dir: str | Path, role: str) -> dict[str, Path]:
    """The files a participant of ``role`` uses: the CA, its certificate and its key.

    Parameters
    ----------
    certs_dir : str or Path
        The folder of the experiment's certificates (``bus.certs_dir``).
    role : str
        The participant.

    Returns
    -------
    dict
        ``"ca"``, ``"certificate"`` and ``"key"`` → their paths (whether they exist or not).
    """
    folder = Path(certs_dir)
    return {
        "ca": folder / CA_FILE,
        "certificate": folder / f"{role}.pem",
        "key": folder / f"{role}.key",
    }


class SecurityError(RuntimeError):
    """A participant cannot take part securely; the message names the file or role."""


def _check_role(mode: str, certs_dir, role: str | None) -> None:
    if not certs_dir:
        raise SecurityError(
            f"bus.security = {mode!r} needs bus.certs_dir (a folder made by 'neuvision certs')"
        )
    if role not in PARTICIPANTS:
        raise SecurityError(
            f"with bus.security = {mode!r} a participant needs a role, one of {PARTICIPANTS}; "
            f"got {role!r}"
        )


def tls_settings(
    certs_dir: str | Path, role: str | None, *, listener: bool, mode: str = "mtls"
) -> dict:
    """Zenoh's ``transport/link/tls`` settings of one participant: mutual TLS (``mode``
    "mtls"), or TLS with the hub's certificate only ("password").

    Parameters
    ----------
    certs_dir : str or Path
        The folder of the experiment's certificates (``bus.certs_dir``).
    role : str or None
        The participant (:data:`PARTICIPANTS`).
    listener : bool
        True for the hub (its certificate is the listening side's).
    mode : str
        ``bus.security``: ``"mtls"`` or ``"password"``.

    Raises
    ------
    SecurityError
        ``role`` is not a participant, or one of its files is missing.
    """
    _check_role(mode, certs_dir, role)
    files = certificate_files(certs_dir, role)
    mutual = mode == "mtls"
    if not (mutual or listener):
        del files["certificate"], files["key"]  # a password, not a key pair, proves the role
    for what, path in files.items():
        if not path.is_file():
            raise SecurityError(
                f"no {what} file {str(path)!r} for the {role} (bus.certs_dir): make it "
                f"with 'neuvision certs {certs_dir} --roles {role}' where the experiment's "
                "CA key (ca.key) is kept, or in an empty folder for a new CA, and give each "
                "participant its own files and ca.pem"
            )
    side = "listen" if listener else "connect"
    settings = {"root_ca_certificate": str(files["ca"]), "enable_mtls": mutual}
    if "certificate" in files:
        settings[f"{side}_certificate"] = str(files["certificate"])
        settings[f"{side}_private_key"] = str(files["key"])
    return settings


def password_settings(certs_dir: str | Path, role: str | None, *, listener: bool) -> dict:
    """Zenoh's ``transport/auth/usrpwd`` settings: the hub's dictionary of passwords, or a
    participant's user (its role) and password.

    Parameters
    ----------
    certs_dir : str or Path
        The folder of the experiment's passwords (``bus.certs_dir``).
    role : str or None
        The participant (:data:`PARTICIPANTS`).
    listener : bool
        True for the hub, which checks the passwords.

    Raises
    ------
    SecurityError
        ``role`` is not a participant, or its password file is missing or empty.
    """
    _check_role("password", certs_dir, role)
    if listener:
        path = Path(certs_dir) / PASSWORDS_FILE
        if not path.is_file():
            raise SecurityError(
                f"no passwords file {str(path)!r} for the hub (bus.certs_dir; make it with "
                f"'neuvision certs {certs_dir} --passwords')"
            )
        return {"dictionary_file": str(path)}
    path = password_file(certs_dir, role)
    password = path.read_text().strip() if path.is_file() else ""
    if not password:
        raise SecurityError(
            f"no password in {str(path)!r} for the {role} (bus.certs_dir; make it with "
            f"'neuvision certs {certs_dir} --roles {role} --passwords' where the hub's are made)"
        )
    return {"user": role, "password": password}


# The nine kinds of message Zenoh's access control tells apart.
_ALL_MESSAGES = [
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
]
_WATCH = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"]


def access_control(keys: Keys, mode: str = "mtls") -> dict:
    """The access-control policy of the hub's router for one session (Zenoh's
    ``access_control`` value): default deny; each rule names what a role may send in.

    Parameters
    ----------
    keys : Keys
        The session's key expressions.
    mode : str
        ``bus.security``: a role is known by its certificate's common name (``"mtls"``)
        or its user name (``"password"``).
    """
    root = keys.root

    def serve(role: str) -> list[str]:
        """An endpoint's own queryables (its description, the run's announcements)."""
        return [keys.describe(role, "*"), keys.run(role, "*")]

    rules = [
        # What the router passes on to any participant it admitted.
        _rule("receive", ["egress"], _ALL_MESSAGES, [f"{root}/**"]),
        _rule("watch", ["ingress"], _WATCH, [f"{root}/**"]),
        _rule(
            "read",
            ["ingress"],
            ["query"],
            [keys.describe("*", "*"), keys.hub_status, f"{keys.hub_view}/*"],
        ),
        _rule("control", ["ingress"], ["query"], [keys.hub_control]),
        _rule("body out", ["ingress"], ["put"], [keys.sensors("*")]),
        _rule("body serves", ["ingress"], ["declare_queryable", "reply"], serve("body")),
        _rule("body alive", ["ingress"], ["liveliness_token"], [keys.alive("body", "*")]),
        _rule("culture out", ["ingress"], ["put"], [keys.spikes("*"), keys.potentials("*")]),
        _rule("culture serves", ["ingress"], ["declare_queryable", "reply"], serve("culture")),
        _rule("culture alive", ["ingress"], ["liveliness_token"], [keys.alive("culture", "*")]),
        # the burst observer: its reports (sealed with the hub's key for the run), its
        # questions for the spikes the hub keeps for it (answered sealed), its run
        # queryable, its liveliness
        _rule("observer out", ["ingress"], ["put"], [keys.observer_reports("*")]),
        _rule("observer asks", ["ingress"], ["query"], [f"{keys.observer_spikes('*')}/*"]),
        _rule(
            "observer serves", ["ingress"], ["declare_queryable", "reply"], [keys.observer_run("*")]
        ),
        _rule("observer alive", ["ingress"], ["liveliness_token"], [keys.alive("observer", "*")]),
    ]
    everyone = ["receive", "watch", "read"]
    policies = [
        {"rules": everyone + ["body out", "body serves", "body alive"], "subjects": ["body"]},
        {
            "rules": everyone + ["culture out", "culture serves", "culture alive"],
            "subjects": ["culture"],
        },
        {
            "rules": everyone
            + ["observer out", "observer asks", "observer serves", "observer alive"],
            "subjects": ["observer"],
        },
        {"rules": everyone + ["control"], "subjects": ["operator"]},
    ]
    by = "cert_common_names" if mode == "mtls" else "usernames"
    subjects = [{"id": role, by: [role]} for role in PARTICIPANTS if role != "hub"]
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def _rule(name: str, flows: list[str], messages: list[str], key_exprs: list[str]) -> dict:
    return {
        "id": name,
        "permission": "allow",
        "flows": flows,
        "messages": messages,
        "key_exprs": key_exprs,
    }


#: how :func:`diagnose` begins when no hub is there (yet): worth waiting for
NOTHING_LISTENS = "nothing listens at"


def diagnose(locator: str, certs_dir: str | Path, role: str | None, mode: str) -> str | None:
    """Why a participant could not join the TLS hub at ``locator``, found by a TLS handshake
    of its own (Zenoh says only "Timeout!"): nothing listening there, the hub's certificate
    not valid for the address or not of this ``ca.pem``, or the hub refusing this
    participant's certificate. None when the handshake goes through (with ``"password"``:
    then the password was refused) or the reason is not known. Takes up to about 3 s.

    Parameters
    ----------
    locator : str
        Where the hub was reached (``tls/HOST:PORT``; another scheme: None).
    certs_dir : str or Path
        The participant's certificate folder (``bus.certs_dir``).
    role : str or None
        The participant.
    mode : str
        ``bus.security``: with ``"mtls"`` the participant's own certificate is shown.
    """
    import socket
    import ssl

    scheme, _, address = locator.partition("/")
    if scheme != "tls" or not role:
        return None
    host, _, port = address.rpartition(":")
    host = host.strip("[]")
    files = certificate_files(certs_dir, role)
    try:
        context = ssl.create_default_context(cafile=str(files["ca"]))
        if mode == "mtls":
            context.load_cert_chain(str(files["certificate"]), str(files["key"]))
    except (OSError, ssl.SSLError):
        return None  # a file missing or unreadable is said when the session is configured
    try:
        with socket.create_connection((host, int(port)), timeout=2.0) as raw:
            with context.wrap_socket(raw, server_hostname=host) as tls:
                tls.settimeout(1.0)
                # a refusal of our certificate comes as an alert; silence: taken, so the TLS
                # link is not the cause
                with contextlib.suppress(TimeoutError):
                    tls.recv(1)
                return None
    except ConnectionRefusedError:
        return f"{NOTHING_LISTENS} {host}:{port} (is the hub started, on that port?)"
    except ssl.SSLCertVerificationError as exc:
        why = exc.verify_message or str(exc)
        if "mismatch" in why or "not valid for" in why:
            return (
                f"the hub's certificate is not valid for {host}: make it with 'neuvision "
                f"certs DIR --roles hub --hub-hosts {host},...' (the addresses and names the "
                f"participants reach it by), or connect by one it names"
            )
        return (
            f"the hub's certificate does not verify against {files['ca']}: {why} (a "
            f"certificate of another CA? every participant needs the experiment's ca.pem)"
        )
    except ssl.SSLError as exc:
        reason = (exc.reason or str(exc)).lower().replace("_", " ")
        return f"the hub refused the {role}'s certificate ({reason})"
    except (OSError, ValueError):
        return None
