"""Zenoh session set-up from the experiment's ``[bus]`` section.

One function builds the Zenoh configuration; nothing else in the project
touches Zenoh configuration keys. See ``reference/zenoh-notes.md`` for why the
defaults are what they are (scouting off, explicit loopback endpoints, 1 s lease).
"""

from __future__ import annotations

import dataclasses
import json
import os
import socket
import time
from collections.abc import Callable

# Zenoh's threads are configured per process, from this variable, when the first session
# opens. One network-receive thread, not two: with two, an arriving message wakes the
# other to steal its work. Zenoh's accept and application work keeps threads of its own:
# handed to the receive thread, it slowed the loop where the hub has a CPU of its own
# (docs/measurements/loop-cost.md). A ZENOH_RUNTIME set by the user is kept as it is.
ZENOH_RUNTIME = "(rx: (worker_threads: 1))"
os.environ.setdefault("ZENOH_RUNTIME", ZENOH_RUNTIME)

import zenoh  # noqa: E402

from hub import security  # noqa: E402
from hub.config import BusSection, ConfigError  # noqa: E402

# Loop messages must not be dropped under load, and should leave at once.
LOOP_PUBLISH = dict(
    congestion_control=zenoh.CongestionControl.BLOCK,
    express=True,
    priority=zenoh.Priority.REAL_TIME,
)
# Telemetry: newest wins — but not for a subscriber that stops reading. Once its socket is
# full, Zenoh holds the putter until it reads again, over the low-latency transport (a
# blocking write) and, as measured, over the queued one too: only small, slow telemetry
# is published (the status); the views are asked for (hub/view.py; docs/dashboard.md,
# "A frozen dashboard").
TELEMETRY_PUBLISH = dict(congestion_control=zenoh.CongestionControl.DROP)


class BusError(RuntimeError):
    """The bus could not be joined; the message says where and why."""


#: how soon an endpoint tries again to open a link to its hub that failed or dropped
RETRY_MS = {"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2}


def zenoh_config(bus: BusSection, *, listener: bool, role: str | None = None) -> zenoh.Config:
    """Build the Zenoh configuration of one participant.

    Parameters
    ----------
    bus : BusSection
        The experiment's bus settings.
    listener : bool
        True for the hub, which listens on ``bus.listen``; False for an
        endpoint, which listens nowhere and connects to ``bus.connect`` (or,
        when empty, to where the hub listens).
    role : str, optional
        Who takes part (:data:`hub.security.PARTICIPANTS`): with ``bus.security`` on it
        picks the certificate or the password; the hub's is ``"hub"``.

    Raises
    ------
    BusError
        With ``bus.security`` on: no certificate or password for ``role`` (the message
        names the file).
    """
    cfg = zenoh.Config()

    def put(key: str, value) -> None:
        cfg.insert_json5(key, json.dumps(value))

    put("mode", bus.hub_mode if listener else bus.mode)
    put("scouting/multicast/enabled", bus.scouting)
    put("scouting/gossip/enabled", bus.scouting)
    put("transport/link/tx/lease", bus.lease_ms)
    # A Zenoh router stamps every message it routes with its own clock (an HLC time). No
    # part of NeuVision reads those stamps (the hub's clocks time the loop), and stamping
    # cost the trivial lockstep loop 7 % placed by the OS (docs/measurements/loop-cost.md).
    put("timestamping/enabled", False)
    put("transport/unicast/lowlatency", bus.low_latency)
    put("transport/unicast/qos/enabled", not bus.low_latency)
    # Zenoh moves payloads over ~3 kB through shared memory between local processes and
    # sets that up on first use: the publish that does it blocks 7-10 ms (a realtime
    # culture's first burst, every run). Loop messages are a few kB: TCP is as fast.
    put("transport/shared_memory/enabled", False)
    if listener:
        put("listen/endpoints", list(bus.listen))
        put("connect/endpoints", [])
    else:
        put("listen/endpoints", [])
        put("connect/endpoints", list(bus.connect or bus.listen))
        # Wait for the hub to come up (endpoints are often started first).
        put("connect/timeout_ms", int(bus.connect_timeout_s * 1000))
        # A link to the hub that dropped (a lease lapsed while this process was frozen or
        # starved) is opened again at once; refused (the hub not done with the old one),
        # tried again within RETRY_MS, not Zenoh's 1-4 s backoff, which would stretch a
        # rejoin, or an observer's final report, by seconds.
        put("connect/retry", RETRY_MS)
    if bus.security != "none":
        who = "hub" if listener else role
        try:
            put(
                "transport/link/tls",
                security.tls_settings(bus.certs_dir, who, listener=listener, mode=bus.security),
            )
            if bus.security == "password":
                put(
                    "transport/auth/usrpwd",
                    security.password_settings(bus.certs_dir, who, listener=listener),
                )
        except security.SecurityError as exc:
            raise BusError(str(exc)) from None
        if listener:
            put("access_control", security.access_control(bus.keys, bus.security))
    return cfg


def check_security_files(bus: BusSection, roles) -> None:
    """With ``bus.security`` on: each of ``roles`` has its certificate or password in
    ``bus.certs_dir``, checked before a folder or a process exists (or a model is built).

    Parameters
    ----------
    bus : BusSection
        The experiment's bus settings (nothing is checked with ``security = "none"``).
    roles : iterable of str
        The participants to check (``hub``, ``body``, ...).

    Raises
    ------
    ConfigError
        A file is missing; the message names it and how to make it.
    """
    for role in roles if bus.security != "none" else ():
        try:
            zenoh_config(bus, listener=role == "hub", role=role)
        except BusError as exc:
            raise ConfigError(str(exc)) from None


#: an endpoint tries to reach its hub for this long at a time, saying so between tries
CONNECT_TRY_S = 2.0


def open_session(
    bus: BusSection,
    *,
    listener: bool,
    role: str | None = None,
    on_wait=None,
    timeout_name: str = "bus.connect_timeout_s",
) -> zenoh.Session:
    """Open a Zenoh session for one participant (caller must close it).

    An endpoint (``listener`` False) whose hub is not up yet keeps trying for
    ``bus.connect_timeout_s``. With ``bus.security`` on, a certificate refused (its own by
    the hub, or the hub's by it: found by a TLS handshake of its own) is said at once:
    waiting would not change it.

    Parameters
    ----------
    bus : BusSection
        The experiment's bus settings.
    listener : bool
        True for the hub (listens on ``bus.listen``); False for any other participant.
    role : str, optional
        Picks the participant's certificate or password when ``bus.security`` is on.
    on_wait : callable, optional
        ``on_wait(where, waited_s)``, called before each new try (to tell the user where
        it is trying).
    timeout_name : str
        What the message calls the wait (a command's own option, where it sets it).

    Raises
    ------
    BusError
        The hub's address cannot be listened on, or the hub was not reached in time: one
        line naming the address.
    """
    where = ", ".join(bus.listen if listener else (bus.connect or bus.listen))
    if listener:
        try:
            return zenoh.open(zenoh_config(bus, listener=True))
        except zenoh.ZError as exc:
            raise BusError(f"cannot listen on {where}: {_first_line(exc)}") from None
    start = time.monotonic()
    while True:
        waited_s = time.monotonic() - start
        left_s = bus.connect_timeout_s - waited_s
        try_bus = dataclasses.replace(bus, connect_timeout_s=max(min(CONNECT_TRY_S, left_s), 0.1))
        try:
            return zenoh.open(zenoh_config(try_bus, listener=False, role=role))
        except zenoh.ZError as exc:
            proof = {"mtls": "certificate", "password": "password"}.get(bus.security)
            seen = None
            if proof:  # Zenoh says only "Timeout!": look at the TLS link ourselves
                seen = security.diagnose(
                    (bus.connect or bus.listen)[0], bus.certs_dir, role, bus.security
                )
            # A certificate refused (ours or the hub's) will be refused again: said now,
            # not after bus.connect_timeout_s of "waiting for the hub"
            refused_now = seen is not None and not seen.startswith(security.NOTHING_LISTENS)
            if refused_now or time.monotonic() - start >= bus.connect_timeout_s:
                refused = (
                    f" (bus.security = {bus.security!r}: its TLS link goes through, so the "
                    f"hub most likely refused the {role}'s {proof})"
                    if proof
                    else ""
                )
                if seen:
                    refused = f" (bus.security = {bus.security!r}: {seen})"
                if refused_now:
                    raise BusError(f"cannot join the hub at {where}{refused}") from None
                raise BusError(
                    f"cannot reach the hub at {where} within {bus.connect_timeout_s:g} s "
                    f"({timeout_name}){refused}: {_first_line(exc)}"
                ) from None
            if on_wait is not None:
                on_wait(where, time.monotonic() - start)


def _first_line(exc: BaseException) -> str:
    """Zenoh's message without the source location it appends."""
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return text.split(" at /")[0]


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port that is free on ``host`` right now (for local runs and tests)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return sock.getsockname()[1]


def payload_bytes(sample) -> bytes:
    """The payload of a Zenoh sample or query as bytes (empty if none)."""
    payload = sample.payload
    return b"" if payload is None else payload.to_bytes()


def hub_answers(session, keys, timeout_s: float = 0.5) -> bool:
    """Whether the hub's liveliness token is on the bus (asked, not waited for).

    Parameters
    ----------
    session : zenoh.Session
        An open session on the hub's bus.
    keys : Keys
        The bus session's key expressions.
    timeout_s : float
        How long the liveliness query waits for answers; a Zenoh error counts as no.
    """
    try:
        replies = session.liveliness().get(keys.hub_alive, timeout=timeout_s)
        return any(reply.ok is not None for reply in replies)
    except zenoh.ZError:
        return False


def reaches_anyone(session) -> bool:
    """Whether this session reaches anyone (a router or a peer): a hub killed takes its
    router with it, and its clients then hear no liveliness change."""
    try:
        return bool(list(session.info.routers_zid()) or list(session.info.peers_zid()))
    except zenoh.ZError:
        return False


#: how often a participant asks whether its hub is still there (an endpoint whose run's
#: inputs stopped; an endpoint or observer serving one run, none taken yet)
HUB_CHECK_S = 1.0
#: the status of a participant serving one run (``--once``) whose hub left without
#: starting it (``neuvision endpoint --once`` and ``observe --once`` exit with it), or,
#: for an endpoint, went in the middle of it without ending it
UNSERVED = 1


class HubWatch:
    """For a participant serving one run (``--once``), none taken yet: whether the hub it
    reached has left, so that it will never get one. Called as often as liked; it looks
    every ``HUB_CHECK_S``. Left: a hub seen before (``there()``, or ``seen`` set from its
    token's news) is no longer there; or a hub never seen (one under another session)
    took its router with it, so that the session reaches no one. Two looks in a row: one
    may fall while a new router's token comes.

    Parameters
    ----------
    session : zenoh.Session
    keys : Keys
    there : callable, optional
        Whether the hub is there now (default: its token answers a liveliness query).
    """

    def __init__(self, session, keys, there: Callable[[], bool] | None = None):
        self.session = session
        self.there = there or (lambda: hub_answers(session, keys))
        self.seen = False  # the hub seen once
        self.reached = False  # someone (a router or a peer) reached once
        self._unanswered = 0
        self._next_look = 0.0

    def __call__(self) -> bool:
        now = time.monotonic()
        if now < self._next_look:
            return False
        self._next_look = now + HUB_CHECK_S
        connected = reaches_anyone(self.session)
        self.reached = self.reached or connected
        if self.there():
            self.seen, self._unanswered = True, 0
        elif self.seen or (self.reached and not connected):
            self._unanswered += 1  # before it was seen, it may be starting
        else:
            self._unanswered = 0
        return self._unanswered >= 2
