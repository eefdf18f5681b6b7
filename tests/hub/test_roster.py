"""Whether an endpoint, as it describes itself, can take the run's loop (hub/roster.py).

The hub asks before it announces the run: a real device cannot be stepped in lockstep, a
device that answers each window after it has passed needs a deadline between one and two
periods, and one whose own I/O cycle is longer than the period is warned about.
"""

from __future__ import annotations

import dataclasses

import pytest

from hub.config import load_config
from hub.errors import HubError
from hub.roster import check_fits_loop
from tests.endpoints import EchoBody, EchoCulture


def loop(*overrides: str):
    return load_config(None, list(overrides)).loop


def test_a_simulator_fits_either_mode():
    for mode in ("lockstep", "realtime"):
        assert check_fits_loop(EchoBody().describe(), loop(f'loop.mode="{mode}"')) is None


def test_a_real_device_is_refused_a_lockstep_run():
    device = dataclasses.replace(EchoBody().describe(), realtime_only=True)
    with pytest.raises(HubError, match='real device.*set loop.mode = "realtime"'):
        check_fits_loop(device, loop('loop.mode="lockstep"'))
    assert check_fits_loop(device, loop('loop.mode="realtime"')) is None


@pytest.mark.parametrize(
    ("deadline_ms", "fits"), [(0.0, False), (10.0, False), (18.0, True), (20.0, False)]
)
def test_a_device_answering_after_its_window_needs_a_deadline_within_two_periods(deadline_ms, fits):
    late = dataclasses.replace(EchoCulture().describe(), answers_after_window=True)
    run = loop('loop.mode="realtime"', "loop.period_ms=10", f"loop.deadline_ms={deadline_ms}")
    if fits:
        assert check_fits_loop(late, run) is None
    else:
        with pytest.raises(HubError, match="between one and two periods .10 and 20 ms"):
            check_fits_loop(late, run)


def test_a_cycle_longer_than_the_period_is_a_warning_not_a_refusal():
    slow = dataclasses.replace(EchoBody().describe(), cycle_ms=35.0)
    warning = check_fits_loop(slow, loop('loop.mode="realtime"', "loop.period_ms=10"))
    assert "35.0 ms, longer than the period of 10 ms" in warning
    assert check_fits_loop(slow, loop('loop.mode="realtime"', "loop.period_ms=50")) is None


def test_a_second_endpoint_that_came_up_after_the_description_is_named_where_it_runs():
    """Two answers to the run's announcement (the second endpoint came up after the hub
    had the first's description): the refusal names each one's host and process id, as a
    refusal at the description does, by asking them again."""
    from hub.protocol import Keys, RunReply, RunStart
    from hub.roster import Roster
    from tests.windows import RUN

    cfg = load_config(None, [])
    keys = Keys(cfg.bus.session)
    described = []
    for pid in (101, 202):
        host = {"hostname": "lab-pc", "pid": pid}
        desc = dataclasses.replace(EchoBody().describe(), counters={"host": host})
        described.append(desc.encode())

    class Link:  # the hub's side of the bus, as the roster asks it
        def __init__(self):
            self.keys = keys

        def query(self, key, payload=None, *, timeout_s):
            if key == keys.describe("body", "0"):
                return described
            return [RunReply(ok=True, run=RUN).encode()] * 2  # to the announcement

    start = RunStart(run=RUN, period_ms=10.0, n_steps=10, mode="lockstep",
                     start_unix_s=1.0, deadline_ms=10.0, key=bytes(16))  # fmt: skip
    with pytest.raises(HubError) as refused:
        Roster(cfg, Link()).announce("body", "0", start)
    assert "2 endpoints answer as body/0" in str(refused.value)
    assert "(lab-pc pid 101, lab-pc pid 202)" in str(refused.value)
