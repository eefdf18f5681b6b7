"""The Zenoh configuration every participant gets from the experiment's [bus] section."""

from __future__ import annotations

import queue
import secrets
import time

import pytest

from hub.bus import free_tcp_port, open_session, zenoh_config
from hub.config import BusSection


@pytest.mark.parametrize("listener", [True, False])
def test_no_scouting_and_no_shared_memory_for_hub_or_endpoint(listener):
    # Shared memory is set up on the first large publish, which then blocks for
    # milliseconds: a realtime step would be late (see hub/bus.py).
    cfg = zenoh_config(BusSection(), listener=listener)
    assert cfg.get_json("scouting/multicast/enabled") == "false"
    assert cfg.get_json("transport/shared_memory/enabled") == "false"


def test_the_hub_listens_and_an_endpoint_connects_to_where_it_listens():
    bus = BusSection()
    hub, endpoint = zenoh_config(bus, listener=True), zenoh_config(bus, listener=False)
    assert hub.get_json("listen/endpoints") == endpoint.get_json("connect/endpoints")
    assert endpoint.get_json("listen/endpoints") == "[]"


def test_the_hub_does_not_stamp_the_messages_it_routes():
    # Nothing reads Zenoh's timestamps, and making them cost the loop (hub/bus.py).
    bus = BusSection(listen=(f"tcp/127.0.0.1:{free_tcp_port()}",), scouting=False)
    hub = open_session(bus, listener=True)
    endpoint = open_session(bus, listener=False)
    try:
        got = queue.Queue()
        prefix = f"nv-test-{secrets.token_hex(4)}"
        to_hub, to_endpoint = f"{prefix}/to-hub", f"{prefix}/to-endpoint"
        hub.declare_subscriber(to_hub, got.put)
        endpoint.declare_subscriber(to_endpoint, got.put)
        deadline = time.monotonic() + 10.0
        samples = []
        while {str(s.key_expr) for s in samples} != {to_hub, to_endpoint}:
            assert time.monotonic() < deadline, "the two puts did not both arrive"
            endpoint.put(to_hub, b"x")
            hub.put(to_endpoint, b"y")
            try:
                while True:
                    samples.append(got.get(timeout=0.1))
            except queue.Empty:
                pass
        routed = {str(s.key_expr): s.timestamp for s in samples}
        assert routed == {to_hub: None, to_endpoint: None}
    finally:
        endpoint.close()
        hub.close()
