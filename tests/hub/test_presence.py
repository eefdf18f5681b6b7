"""What an endpoint's token coming and going means during a run (hub/presence.py): a death,
a rejoin awaited, or the hub's own stall named as the cause."""

from __future__ import annotations

import pytest

from hub.config import load_config
from hub.errors import EndpointDied, HubError
from hub.ledger import Ledger
from hub.presence import Presence
from hub.steps import Standing

LEASE_S = 1.0  # bus.lease_ms's default, 1000 ms


class Steps:
    """The scheduler as Presence sees it: the step under way, told of a return."""

    k = 7

    def rejoined(self, role):
        self.back = role


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


@pytest.fixture
def clock(monkeypatch):
    clock = Clock()
    monkeypatch.setattr("hub.presence.time.monotonic", clock)
    return clock


def presence(*overrides) -> tuple[Presence, Standing, str]:
    cfg = load_config(None, list(overrides))
    standing = Standing()
    events = []
    p = Presence(cfg, standing, Ledger(), Steps(), None, lambda role: None,
                 lambda name, **d: events.append(name))  # fmt: skip
    body = cfg.bus.keys.alive("body", cfg.body.id)
    p.seen(body, True)
    return p, standing, body


def stepping(p: Presence, standing: Standing) -> None:
    standing.state = "running"
    p.steps_start()


def test_a_vanished_endpoint_is_dead_and_named(clock):
    p, standing, body = presence()
    stepping(p, standing)
    with pytest.raises(EndpointDied, match="body/0 died at step 7"):
        p.seen(body, False)


def test_a_vanishing_just_after_the_hub_stalled_is_the_hubs_doing(clock):
    p, standing, body = presence()
    stepping(p, standing)
    clock.now += 0.9  # the hub frozen: no wake for 0.9 s (> flush 0.5 s + lease / 4)
    p.note_wake()
    clock.now += 0.5
    with pytest.raises(HubError, match=r"the hub itself stopped running for 0.9 s"):
        p.seen(body, False)


def test_a_stall_long_before_the_vanishing_is_not_blamed(clock):
    p, standing, body = presence()
    stepping(p, standing)
    clock.now += 0.9
    p.note_wake()
    clock.now += 2 * LEASE_S + 0.1  # the loop ran on since: its leases were kept
    with pytest.raises(EndpointDied):
        p.seen(body, False)


def test_the_time_before_the_steps_is_no_stall(clock):
    p, standing, body = presence()
    clock.now += 1.2  # the endpoints described, the run announced: the thread at work
    stepping(p, standing)
    p.note_wake()
    with pytest.raises(EndpointDied):
        p.seen(body, False)


def test_with_rejoin_s_an_endpoint_is_awaited_back_even_after_a_stall(clock):
    p, standing, body = presence("policy.rejoin_s=5")
    stepping(p, standing)
    clock.now += 0.9
    p.note_wake()
    p.seen(body, False)  # not a fault: it may come back
    assert standing.awaited == {"body": (clock.now, 7)}
    clock.now += 1.0
    p.seen(body, True)
    assert p.rejoins[0]["gap_s"] == 1.0 and p.steps.back == "body"


class Reply:
    """A reply as the ledger sees it: its step."""

    def __init__(self, step):
        self.step = step


def test_an_endpoint_whose_replies_are_all_stood_in_for_silent_s_is_dead(clock):
    p, standing, _ = presence("policy.silent_s=30")
    stepping(p, standing)
    p.ledger.miss("body", 5)
    clock.now += 29.0
    p.check_silent()  # not yet
    clock.now += 2.0
    with pytest.raises(EndpointDied, match=r"body/0 died at step 7 \(it answered none of its"):
        p.check_silent()


def test_a_reply_that_comes_even_late_ends_the_silence(clock):
    p, standing, _ = presence("policy.silent_s=30")
    stepping(p, standing)
    ledger = p.ledger
    ledger.sent("body", 5)
    ledger.miss("body", 5)
    clock.now += 20.0
    assert ledger.judge("body", Reply(5), clock.now, running=True) == "late"
    ledger.miss("body", 6)
    clock.now += 20.0  # 40 s since the first miss, 20 s since it answered
    p.check_silent()
    assert list(ledger.silent_since) == ["body"]


def test_silence_is_judged_only_while_the_steps_run(clock):
    p, standing, _ = presence("policy.silent_s=30")
    stepping(p, standing)
    p.ledger.miss("body", 5)
    clock.now += 60.0
    standing.state = "paused"
    p.check_silent()  # not judged while paused
    standing.state = "running"
    with pytest.raises(EndpointDied):
        p.check_silent()


def test_with_silent_s_0_silence_is_never_judged(clock):
    p, standing, _ = presence("policy.silent_s=0")
    stepping(p, standing)
    p.ledger.miss("body", 5)
    clock.now += 3600.0
    p.check_silent()  # does not raise
    assert p.ledger.silent(clock.now, 1.0) == ["body"]  # silent all the same


def test_with_endpoint_death_continue_a_silent_endpoint_is_said_once(clock, caplog):
    p, standing, _ = presence("policy.silent_s=30", 'policy.endpoint_death="continue"')
    stepping(p, standing)
    p.ledger.miss("body", 5)
    clock.now += 31.0
    p.check_silent()
    p.check_silent()
    said = [r for r in caplog.records if "answered none of its inputs" in r.getMessage()]
    assert len(said) == 1 and said[0].levelname == "ERROR"


def test_an_endpoint_whose_token_went_is_not_said_silent_as_well(clock, caplog):
    p, standing, body = presence("policy.silent_s=30", 'policy.endpoint_death="continue"')
    stepping(p, standing)
    p.seen(body, False)  # dead, and the run goes on
    p.ledger.miss("body", 5)
    clock.now += 31.0
    p.check_silent()
    assert [r.getMessage()[:22] for r in caplog.records if r.levelname == "ERROR"] == [
        "body/0 died at step 7 "
    ]
