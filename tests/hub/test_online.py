"""The hub's side of live burst detection, without a bus (hub/online.py): what it records
of the burst observer's reports, and of its going and coming back."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from hub.config import load_config
from hub.launch import LocalProcess
from hub.online import OnlineAnalysis
from hub.protocol import BurstReport, ObserverStart, ProtocolError, RunReply

RUN = "5e" * 16  # the run's id


def analysis(step: list[int]):
    events = []
    online = OnlineAnalysis(
        load_config(None, []),
        RUN,
        lambda name, **details: events.append((name, details)),
        lambda: step[0],
    )
    return online, events


def report(**fields) -> BurstReport:
    base = dict(run=RUN, bursts=3, network_bursts=0, until_ms=1000.0)
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
    online.take_report(report(run="0e" * 16, network_bursts=2))
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


class ObserverLink:
    """Stands in for the hub's link to the burst observer: takes the run, and answers
    each ``ObserverEnd`` with the next of ``end_answers`` (a list of reports; none left:
    nothing answers)."""

    def __init__(self, keys, end_answers: list[list[BurstReport]]):
        self.keys = keys
        self.end_answers = end_answers
        self.ends_asked = 0

    def watch_observer(self, name, key, keep):
        pass

    def forward_spikes(self, raw):
        pass

    def query(self, key, payload=None, *, timeout_s):
        try:
            ObserverStart.decode(payload)
            return [RunReply(ok=True, run=RUN).encode()]
        except ProtocolError:  # an ObserverEnd
            pass
        self.ends_asked += 1
        answers = self.end_answers.pop(0) if self.end_answers else []
        return [a.encode() for a in answers]


@pytest.fixture
def observer_process():
    """A process that runs as long as the test: the observer the hub started, alive."""
    popen = subprocess.Popen(["sleep", "120"])
    yield LocalProcess("observer", popen, None)
    popen.kill()
    popen.wait()


def ended(end_answers, *, there: bool, process=None) -> tuple[OnlineAnalysis, ObserverLink]:
    """A run's observer announced, then asked for its final report after 100 steps."""
    online, _ = analysis([100])
    online.process = process
    link = ObserverLink(online.cfg.bus.keys, end_answers)
    online.announce(link, 100, np.arange(4, dtype=np.uint32))
    online.end(100, there=lambda: there, take_waiting=lambda: None)
    return online, link


def test_the_observer_the_hub_started_is_asked_even_while_its_token_looks_gone(
    observer_process,
):
    """Its token's going can be seen after its return (the old link closing late)."""
    online, link = ended([[report(final=True)]], there=False, process=observer_process)
    assert online.tally.final and online.tally.counts()["online_analysis"] == "complete"
    assert link.ends_asked == 1


def test_an_observer_whose_question_ended_unanswered_is_asked_again(observer_process):
    online, link = ended([[], [], [report(final=True)]], there=True, process=observer_process)
    assert online.tally.final and link.ends_asked == 3


def test_an_observer_away_longer_than_END_ABSENT_S_is_not_waited_for(observer_process, monkeypatch):
    monkeypatch.setattr("hub.online.END_ABSENT_S", 0.2)
    online, link = ended([], there=False, process=observer_process)
    assert not online.tally.final and link.ends_asked >= 1
    assert online.tally.counts()["online_analysis"] == (
        "incomplete: the burst observer was not there at the run's end"
    )


def test_an_observer_run_elsewhere_and_not_there_is_not_asked():
    online, link = ended([[report(final=True)]], there=False, process=None)
    assert link.ends_asked == 0 and not online.tally.final
    assert online.tally.lost == "the burst observer was not there at the run's end"
