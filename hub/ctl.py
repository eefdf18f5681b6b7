"""The hub's control key from outside: ``status``, ``pause``, ``resume``, ``stop``, ``config``.

What ``neuvision ctl`` and the dashboard send to a running hub: a :class:`ControlRequest`
as the payload of a query on ``nv/<session>/hub/control``, answered by the hub's loop
with a :class:`ControlReply` (whether it was taken, the hub's state, its status or
config). Nothing here keeps state; a caller with a session of its own uses
:func:`request`, one without :func:`ctl`.
"""

from __future__ import annotations

import dataclasses
import time

from hub import wire
from hub.bus import open_session
from hub.config import BusSection
from hub.protocol import ControlReply, ControlRequest, Keys, ProtocolError

#: between two queries of a router that answered nothing (no hub's queryable there yet)
RETRY_S = 0.2


def request(session, keys: Keys, cmd: str, *, timeout_s: float = 5.0) -> ControlReply | None:
    """Ask the hub of ``keys``'s session to ``cmd``; its reply, or None if no hub answered.

    Parameters
    ----------
    session : zenoh.Session
        An open session on the hub's bus.
    keys : Keys
        The bus session's key expressions.
    cmd : str
        One of :data:`hub.protocol.CONTROL_COMMANDS`.
    timeout_s : float
        How long to wait for the reply.

    Raises
    ------
    ProtocolError
        ``cmd`` is not a control command.
    """
    payload = ControlRequest(cmd=cmd).encode()
    for raw in wire.get(session, keys.hub_control, payload, timeout_s=timeout_s):
        try:
            return ControlReply.decode(raw)
        except ProtocolError:
            continue
    return None


def ctl(
    bus: BusSection, cmd: str, *, timeout_s: float = 5.0, timeout_name: str = "timeout_s"
) -> ControlReply | None:
    """:func:`request` over a session of its own, opened as a client of the hub's router
    and closed after. With ``bus.security`` on it takes part as an ``operator`` (the role
    that may send controls).

    Parameters
    ----------
    bus : BusSection
        The hub's bus settings (where its router is, security).
    cmd : str
        One of :data:`hub.protocol.CONTROL_COMMANDS`.
    timeout_s : float
        How long to try to reach the router and get a reply, in all.
    timeout_name : str
        The name of that wait in the message of a hub not reached.

    Returns
    -------
    ControlReply or None
        The hub's reply, or None if no hub answered in time.

    Raises
    ------
    hub.bus.BusError
        The hub's router was not reached.
    """
    deadline = time.monotonic() + timeout_s
    bus = dataclasses.replace(bus, connect_timeout_s=timeout_s)
    session = open_session(bus, listener=False, role="operator", timeout_name=timeout_name)
    try:
        # The router may be up before its hub's control queryable (a hub just started),
        # and then answers at once with nothing: ask again until the time is up.
        while True:
            left_s = deadline - time.monotonic()
            reply = request(session, bus.keys, cmd, timeout_s=max(left_s, 0.1))
            if reply is not None or deadline - time.monotonic() < RETRY_S:
                return reply
            time.sleep(RETRY_S)
    finally:
        session.close()
