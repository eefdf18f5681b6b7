"""The closed loop across hosts: the hub on one, the culture and the arena each on another
(Linux network namespaces joined by veth links), against the same run on one host."""

from __future__ import annotations

import dataclasses

import pytest

from hub.protocol import MotorCommand, SensorReading, SpikeBatch, Stimulation
from tests.netns import UNAVAILABLE, closed_loop, hosts

pytestmark = pytest.mark.skipif(bool(UNAVAILABLE), reason=UNAVAILABLE or "")


def _content(record, kind, direction):
    """Every message of ``kind``, by step, without the run's id (new for each run)."""
    out = {}
    for m in record.decoded(kind, direction):
        fields = {
            f.name: getattr(m, f.name) for f in dataclasses.fields(m) if f.name not in ("run",)
        }
        out[m.step] = {
            k: v.tolist() if hasattr(v, "tolist") else v for k, v in sorted(fields.items())
        }
    return out


@pytest.mark.slow  # three hosts' runs
def test_a_lockstep_run_across_three_hosts_is_the_same_run_step_for_step(tmp_path):
    here, _ = closed_loop(tmp_path, "one-host", None)
    with hosts(["body", "culture"]) as places:
        there, _ = closed_loop(tmp_path, "three-hosts", places)
        links = [f"tcp/{h.hub_ip}:" for h in places.values()]
    # The hub listened on the two links only: the endpoints came over them.
    listen = there.manifest["config"]["bus"]["listen"]
    assert [a.rsplit(":", 1)[0] + ":" for a in listen] == links
    for kind, direction in (
        (SensorReading, "rx"),
        (SpikeBatch, "rx"),
        (MotorCommand, "tx"),
        (Stimulation, "tx"),
    ):
        a, b = _content(here, kind, direction), _content(there, kind, direction)
        assert len(a) >= 100 and a == b, kind.__name__
