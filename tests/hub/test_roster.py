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
