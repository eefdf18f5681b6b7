"""The closed loop in realtime over slow links: each endpoint reaches the hub through a relay
that delays every message (tests/delay_link.py, ``tc netem delay`` where the kernel has no
netem). A few milliseconds each way fit in a 20 ms step; tens do not, and then the policy
stands in for what came late and the run still completes."""

from __future__ import annotations

import time

import pytest

from hub.protocol import MotorCommand, Stimulation
from tests.delay_link import DelayLink, delayed_closed_loop
from tests.stall_witness import StallWitness

pytestmark = pytest.mark.bus


def test_the_link_holds_each_chunk_for_its_delay_and_keeps_order():
    import socket

    server = socket.create_server(("127.0.0.1", 0))
    with DelayLink(server.getsockname()[1], delay_ms=30.0, jitter_ms=10.0, seed=1) as link:
        near = socket.create_connection(("127.0.0.1", link.port))
        far, _ = server.accept()
        far.settimeout(5)
        sent_at, got, seen = time.monotonic(), b"", []
        for i in range(20):
            near.sendall(b"%02d" % i)
            time.sleep(0.002)
        while len(got) < 40:
            got += far.recv(64)
            seen.append(time.monotonic() - sent_at)
        assert got == b"".join(b"%02d" % i for i in range(20))  # in order, whatever the jitter
        assert seen[0] >= 0.019  # 30 ms - 10 ms at the least
        near.close()
        far.close()
    server.close()


@pytest.mark.slow
def test_a_realtime_run_over_5_ms_links_has_no_late_step_but_where_the_host_stalled(tmp_path):
    # A round trip carries up to 2 x (5 + 2) ms of link and the culture's step besides: a
    # 30 ms period leaves it room on a loaded 2-core machine (at 20 ms a CI run saw a reply
    # 21 ms after its step's start, 2 late steps of 250; the benchmark's 20 ms figure is
    # bench/remote.py's).
    with StallWitness() as witness:
        record, result, chunks = delayed_closed_loop(
            tmp_path, "delay5", 5.0, 2.0, "loop.period_ms=30", "experiment.duration_s=6"
        )
    assert result.outcome == "completed" and result.steps == 200
    assert all(n > 200 for n in chunks.values())  # every step's messages went through them
    timing = record.manifest["timing"]
    # none late, but where the host held a CPU (tests/stall_witness.py)
    excused = witness.explains_every_miss(record)
    assert timing["late_steps"] == 0 or excused, (timing, witness.summary())
    # The round trips carry both directions' delays: at least 2 x (5 - 2) ms.
    for role in ("body", "culture"):
        assert timing["round_trip_ms"][role]["median"] >= 6.0, timing["round_trip_ms"]


@pytest.mark.slow
def test_over_30_ms_links_late_replies_are_counted_the_policy_stands_in_and_the_run_ends(
    tmp_path,
):
    record, result, _ = delayed_closed_loop(
        tmp_path, "delay30", 30.0, 0.0, "loop.period_ms=20", "experiment.duration_s=3"
    )
    assert result.outcome == "completed" and result.steps == 150
    counts = record.manifest["counts"]
    assert counts["late"].get("culture", 0) + counts["missing"].get("culture", 0) > 100
    assert record.manifest["timing"]["late_steps"] > 100
    # The stand-in kept the loop going: a motor command and a stimulation went out every step.
    assert len(record.decoded(MotorCommand, "tx")) >= 150
    assert len(record.decoded(Stimulation, "tx")) >= 150
