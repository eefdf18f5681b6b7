"""Zenoh session set-up from the experiment's ``[bus]`` section.

One function builds the Zenoh configuration; nothing else in the project
touches Zenoh configuration keys. See ``reference/zenoh-notes.md`` for why the
defaults are what they are (scouting off, explicit loopback endpoints, 1 s lease).
"""

from __future__ import annotations

import json
import os
import socket

# Zenoh's threads are configured per process, from this variable, when the first session
# opens. One network-receive thread, not two: with two, each arriving message wakes both
# (one to steal the other's work), a wake-up per message more on every step's critical
# path (bench/loop.py: ~10 % more lockstep steps per second on 2 cores). A
# ZENOH_RUNTIME set by the user is kept as it is.
ZENOH_RUNTIME = "(rx: (worker_threads: 1))"
os.environ.setdefault("ZENOH_RUNTIME", ZENOH_RUNTIME)

import zenoh  # noqa: E402

from hub.config import BusSection  # noqa: E402

# Loop messages must not be dropped under load, and should leave at once.
LOOP_PUBLISH = dict(
    congestion_control=zenoh.CongestionControl.BLOCK,
    express=True,
    priority=zenoh.Priority.REAL_TIME,
)
# Telemetry: newest wins, never block the loop.
TELEMETRY_PUBLISH = dict(congestion_control=zenoh.CongestionControl.DROP)


def zenoh_config(bus: BusSection, *, listener: bool) -> zenoh.Config:
    """Build the Zenoh configuration of one participant.

    Parameters
    ----------
    bus : BusSection
        The experiment's bus settings.
    listener : bool
        True for the hub, which listens on ``bus.listen``; False for an
        endpoint, which listens nowhere and connects to ``bus.connect`` (or,
        when empty, to where the hub listens).
    """
    cfg = zenoh.Config()

    def put(key: str, value) -> None:
        cfg.insert_json5(key, json.dumps(value))

    put("mode", bus.hub_mode if listener else bus.mode)
    put("scouting/multicast/enabled", bus.scouting)
    put("scouting/gossip/enabled", bus.scouting)
    put("transport/link/tx/lease", bus.lease_ms)
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
    return cfg


class BusError(RuntimeError):
    """The bus could not be joined; the message says where and why."""


def open_session(bus: BusSection, *, listener: bool) -> zenoh.Session:
    """Open a Zenoh session for one participant (caller must close it)."""
    try:
        return zenoh.open(zenoh_config(bus, listener=listener))
    except zenoh.ZError as exc:
        where = ", ".join(bus.listen if listener else (bus.connect or bus.listen))
        verb = "listen on" if listener else "reach the hub at"
        raise BusError(f"cannot {verb} {where}: {exc}") from None


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port that is free on ``host`` right now (for local runs and tests)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return sock.getsockname()[1]


def payload_bytes(sample) -> bytes:
    """The payload of a Zenoh sample or query as bytes (empty if none)."""
    payload = sample.payload
    return b"" if payload is None else payload.to_bytes()
