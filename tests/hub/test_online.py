"""The hub's side of live burst detection, without a bus (hub/online.py): what it records
of the burst observer's reports, and of its going and coming back."""

from __future__ import annotations

import numpy as np

from hub.config import load_config
from hub.online import OnlineAnalysis
from hub.protocol import BurstReport


def analysis(step: list[int]):
    events = []
    online = OnlineAnalysis(
        load_config(None, []),
        "run-1",
        lambda name, **details: events.append((name, details)),
        lambda: step[0],
    )
    return online, events


def report(**fields) -> BurstReport:
    base = dict(run="run-1", bursts=3, network_bursts=0, until_ms=1000.0)
    return BurstReport(**{**base, **fields})


def test_a_network_burst_reported_is_recorded_once_with_the_step_it_came_at():
    step = [40]
    online, events = analysis(step)
    burst = {
        "nb_start_ms": np.array([100.0]),
        "nb_end_ms": np.array([180.0]),
        "nb_core_start_ms": np.array([110.0]),
        "nb_core_end_ms": np.array([170.0]),
        "nb_channels": np.array([12], np.uint32),
    }
    online.take_report(report(network_bursts=1, **burst))
    step[0] = 90
    online.take_report(report(network_bursts=1, until_ms=2000.0, final=True, **burst))
    recorded = [d for name, d in events if name == "network_burst"]
    assert [(d["start_ms"], d["end_ms"], d["n_channels"], d["at_step"]) for d in recorded] == [
        (100.0, 180.0, 12, 40)
    ]
    assert online.tally.final and online.tally.network_bursts == 1


def test_a_report_of_another_run_is_left_out():
    online, events = analysis([0])
    online.take_report(report(run="run-0", network_bursts=2))
    assert online.tally.network_bursts == 0 and not events


def test_an_observer_that_vanished_and_came_back_is_a_rejoin_and_not_lost():
    step = [10]
    online, events = analysis(step)
    assert online.came_or_went(False) is None
    assert online.tally.lost == "the burst observer vanished at step 10"
    step[0] = 25
    entry = online.came_or_went(True)
    assert entry["gone_at_step"] == 10 and entry["at_step"] == 25 and entry["gap_s"] >= 0
    assert online.tally.lost == ""
    assert [name for name, _ in events] == ["rejoined"]
    assert online.came_or_went(True) is None  # there already: nothing to note
