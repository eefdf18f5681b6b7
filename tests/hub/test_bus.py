"""The Zenoh configuration every participant gets from the experiment's [bus] section."""

from __future__ import annotations

import queue
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
    # Nothing reads Zenoh's timestamps; making them cost the loop (hub/bus.py).
    bus = BusSection(listen=(f"tcp/127.0.0.1:{free_tcp_port()}",), scouting=False)
    hub = open_session(bus, listener=True)
    endpoint = open_session(bus, listener=False)
    try:
        got = queue.Queue()
        hub.declare_subscriber("nv-test/stamps/to-hub", got.put)
        endpoint.declare_subscriber("nv-test/stamps/to-endpoint", got.put)
        deadline = time.monotonic() + 10.0
        samples = []
        while len(samples) < 2 and time.monotonic() < deadline:
            endpoint.put("nv-test/stamps/to-hub", b"x")
            hub.put("nv-test/stamps/to-endpoint", b"y")
            try:
                while True:
                    samples.append(got.get(timeout=0.1))
            except queue.Empty:
                pass
        routed = {str(s.key_expr): s.timestamp for s in samples}
        assert routed == {"nv-test/stamps/to-hub": None, "nv-test/stamps/to-endpoint": None}
    finally:
        endpoint.close()
        hub.close()
