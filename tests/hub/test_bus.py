"""The Zenoh configuration every participant gets from the experiment's [bus] section."""

from __future__ import annotations

import pytest

from hub.bus import zenoh_config
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
