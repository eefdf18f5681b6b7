"""``neuvision certs``: a small certificate authority and one certificate per participant.

Each certificate's common name is the participant's role (what the hub's access control
matches, :mod:`hub.security`); the hub's also names the hosts the others reach it by, so
that they can check they talk to the real hub. Keys are EC P-256, written readable by the
owner only. The CA's key stays in the folder: keep that folder on the machine that makes
certificates, and copy to each machine only ``ca.pem`` and that participant's two files.

Built on ``cryptography`` (PyCA), the well-kept standard for X.509 in Python: no home-made
crypto.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
import secrets
import socket
from pathlib import Path

from hub.security import CA_FILE, PARTICIPANTS, PASSWORDS_FILE, certificate_files, password_file

CA_KEY_FILE = "ca.key"
CA_NAME = "NeuVision experiment CA"
MAX_DAYS = 36_500  # a hundred years: past that, dates overflow X.509's


class CertsError(ValueError):
    """A certificate folder that cannot be used as asked (the message says why)."""


#: where the hub is always reached: the processes it starts itself (the burst observer)
LOOPBACK_HOSTS = ["127.0.0.1", "localhost"]


def default_hub_hosts() -> list[str]:
    """Names the hub is reached by on one machine: loopback and this host's name."""
    return [*LOOPBACK_HOSTS, socket.gethostname()]


def make_certificates(
    folder: str | Path,
    roles: list[str],
    *,
    hub_hosts: list[str] | None = None,
    days: int = 365,
) -> list[Path]:
    """Write ``ca.pem`` (and its key, once) and ``<role>.pem`` / ``<role>.key`` for each role.

    An existing CA in ``folder`` is kept and signs the new certificates, so that a
    participant can be added later; a role's existing files are replaced.

    Parameters
    ----------
    folder : str or Path
        Where the files go (made if missing).
    roles : list of str
        Participants (:data:`hub.security.PARTICIPANTS`) to make a certificate for.
    hub_hosts : list of str, optional
        Host names and IP addresses other machines reach the hub by, named in every
        certificate with :data:`LOOPBACK_HOSTS` (the hub's own burst observer reaches it
        there); default: :func:`default_hub_hosts`.
    days : int
        How long the certificates (and a new CA) stay valid, from now; no longer than an
        existing CA's own certificate, which a certificate cannot outlive.

    Returns
    -------
    list of Path
        The files written.

    Raises
    ------
    ValueError
        A role that is not a participant, or a host name that is empty.
    CertsError
        ``folder`` holds the CA's certificate without its key, or the key without the
        certificate: a participant's folder (which holds ``ca.pem`` only), where a new CA
        would replace the one every other participant trusts.
    """
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    unknown = [r for r in roles if r not in PARTICIPANTS]
    if unknown or not roles:
        raise ValueError(f"roles must be some of {', '.join(PARTICIPANTS)}; got {roles}")
    hosts = default_hub_hosts() if hub_hosts is None else hub_hosts
    if any(not h.strip() for h in hosts):
        raise ValueError(f"an empty hub host name in {hosts}")
    hosts = list(dict.fromkeys([*LOOPBACK_HOSTS, *hosts]))
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.UTC)
    valid_from, valid_to = now - datetime.timedelta(minutes=5), now + datetime.timedelta(days)
    written: list[Path] = []

    def write(path: Path, data: bytes, *, secret: bool) -> None:
        if path.exists():
            path.unlink()
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600 if secret else 0o644)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        written.append(path)

    def key_pem(key) -> bytes:
        return key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )

    ca_path, ca_key_path = folder / CA_FILE, folder / CA_KEY_FILE
    if ca_path.exists() != ca_key_path.exists():
        here, missing = (ca_path, ca_key_path) if ca_path.exists() else (ca_key_path, ca_path)
        raise CertsError(
            f"{folder} holds {here.name} but not {missing.name}: make certificates in the "
            f"folder where the CA's key ({CA_KEY_FILE}) is kept and copy them here (a "
            f"participant's folder holds {CA_FILE} only), or give an empty folder for a new "
            "CA; nothing was written"
        )
    if ca_path.exists():
        ca = x509.load_pem_x509_certificate(ca_path.read_bytes())
        ca_key = serialization.load_pem_private_key(ca_key_path.read_bytes(), password=None)
        valid_to = min(valid_to, ca.not_valid_after_utc)
    else:
        ca_key = ec.generate_private_key(ec.SECP256R1())
        name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, CA_NAME)])
        ca = (
            x509.CertificateBuilder()
            .subject_name(name)
            .issuer_name(name)
            .public_key(ca_key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(valid_from)
            .not_valid_after(valid_to)
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(
                x509.KeyUsage(
                    digital_signature=True,
                    key_cert_sign=True,
                    crl_sign=True,
                    content_commitment=False,
                    key_encipherment=False,
                    data_encipherment=False,
                    key_agreement=False,
                    encipher_only=False,
                    decipher_only=False,
                ),
                critical=True,
            )
            .sign(ca_key, hashes.SHA256())
        )
        write(ca_key_path, key_pem(ca_key), secret=True)
        write(ca_path, ca.public_bytes(serialization.Encoding.PEM), secret=False)

    for role in roles:
        key = ec.generate_private_key(ec.SECP256R1())
        builder = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, role)]))
            .issuer_name(ca.subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(valid_from)
            .not_valid_after(valid_to)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(
                x509.ExtendedKeyUsage(
                    [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
                ),
                critical=False,
            )
        )
        # Every certificate names the hub's hosts: Zenoh's TLS wants a subject name on
        # each side's certificate; only the hub's is checked against where it is reached.
        builder = builder.add_extension(
            x509.SubjectAlternativeName([_san(h) for h in hosts]), critical=False
        )
        cert = builder.sign(ca_key, hashes.SHA256())
        files = certificate_files(folder, role)
        write(files["key"], key_pem(key), secret=True)
        write(files["certificate"], cert.public_bytes(serialization.Encoding.PEM), secret=False)
    return written


def make_passwords(folder: str | Path, roles: list[str]) -> list[Path]:
    """Write a fresh random password for each role but the hub (``<role>.password``) and
    the hub's dictionary of them (``passwords``), keeping other roles' entries; both
    readable by their owner only.

    Parameters
    ----------
    folder : str or Path
        Where the files go (made if missing).
    roles : list of str
        Participants (:data:`hub.security.PARTICIPANTS`); ``hub`` gets no password.

    Returns
    -------
    list of Path
        The files written.

    Raises
    ------
    ValueError
        A role that is not a participant.
    """
    unknown = [r for r in roles if r not in PARTICIPANTS]
    if unknown or not roles:
        raise ValueError(f"roles must be some of {', '.join(PARTICIPANTS)}; got {roles}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    dictionary = folder / PASSWORDS_FILE
    known = {}
    if dictionary.is_file():
        for line in dictionary.read_text().splitlines():
            user, sep, password = line.partition(":")
            if sep:
                known[user] = password
    written = []
    for role in roles:
        if role == "hub":  # the hub checks passwords; it shows its certificate
            continue
        known[role] = secrets.token_urlsafe(24)
        written.append(_write_secret(password_file(folder, role), known[role] + "\n"))
    if not known:  # only the hub asked for: no password, and no dictionary to write
        return written
    text = "".join(f"{user}:{password}\n" for user, password in known.items())
    written.append(_write_secret(dictionary, text))
    return written


def _write_secret(path: Path, text: str) -> Path:
    tmp = path.with_name(path.name + ".tmp")
    tmp.unlink(missing_ok=True)
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)
    return path


def _san(host: str):
    from cryptography import x509

    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        return x509.DNSName(host)
