"""The realtime scheduler (hub/realtime.py), on a clock of the test's: when each step
starts, what it sends, how long it waits for each reply, what it counts late, and where
the loop's chores go.

The scheduler sees the hub only through its services (:class:`hub.steps.LoopPort`); a port
of the test's plays them: endpoints that answer each input after a delay of the test's (or
never), replies that reach the loop's thread when it waits, a real ledger that judges each
by its arrival, the loop's chores falling due on a period of their own. No bus, no hub.
"""

from __future__ import annotations

import heapq
import itertools
import math
from types import SimpleNamespace

import pytest

from hub.config import load_config
from hub.ledger import Ledger
from hub.realtime import LATE_START_SHARE, VIEW_GUARD_S, Realtime
from hub.report import LoopTimes
from hub.steps import Standing
from tests.hub.scheduler_parts import Inputs, Reply

PERIOD_S = 0.01


class Clock:
    """The test's clock: it moves only when the port waits (or a chore takes time)."""

    def __init__(self):
        self.now = 100.0

    def monotonic(self) -> float:
        return self.now

    perf_counter = monotonic

    def process_time(self) -> float:
        return 0.0


class Port:
    """The hub and the endpoints as the realtime scheduler sees them (hub.steps.LoopPort).

    ``reply_s(role, step)`` is how long after its input an endpoint's reply comes (None:
    never); the loop's chores fall due every ``chores_every_s``. Everything the scheduler
    does is logged with the clock's time: ``(t, what, ...)``.
    """

    def __init__(self, clock, ledger, standing, reply_s, chores_every_s=math.inf):
        self.clock, self.ledger, self.standing, self.reply_s = clock, ledger, standing, reply_s
        self.chores_every_s = chores_every_s
        self.chores_due = clock.now + chores_every_s
        self.chore_s = 0.0  # how long the next chores take
        self.on_tick = lambda t: None  # what the test does at each tick (a pause, a stop)
        self.view_due_at = 0.0
        self.log: list[tuple] = []
        self._replies: list[tuple] = []  # (arrival, order, role, step), earliest first
        self._order = itertools.count()

    def send(self, role, message, raw=None):
        self.ledger.sent(role, message.step)
        self.log.append((self.clock.now, "send", role, message.step, message.source))
        delay_s = self.reply_s(role, message.step)
        if delay_s is not None:
            arrival = self.clock.now + delay_s
            heapq.heappush(self._replies, (arrival, next(self._order), role, message.step))

    def wait_event(self, until):
        """The next reply, if one comes by ``until`` and before the chores fall due."""
        first = self._replies[0][0] if self._replies else math.inf
        self.clock.now = max(self.clock.now, min(until, first, self.chores_due))
        if first <= self.clock.now:
            arrival, _, role, step = heapq.heappop(self._replies)
            return ("rx", role, Reply(step), 0, arrival)
        return None

    def drain(self):
        while self._replies and self._replies[0][0] <= self.clock.now:
            arrival, _, role, step = heapq.heappop(self._replies)
            self.handle(("rx", role, Reply(step), 0, arrival))

    def handle(self, item):
        _, role, reply, _, arrival = item
        self.log.append((self.clock.now, "taken", role, reply.step))
        self.ledger.judge(role, reply, arrival, running=True)

    def tick(self):
        now = self.clock.now
        self.log.append((now, "tick"))
        if now >= self.chores_due:
            self.chores_due = now + self.chores_every_s
        self.on_tick(now)
        self.clock.now += self.chore_s
        self.chore_s = 0.0

    def share(self, now, *, view=True):
        self.log.append((now, "share", view))

    def record_event(self, name, **details):
        self.log.append((self.clock.now, name, details))

    def post(self, item):
        raise AssertionError("realtime replies come through the loop's thread")

    def resend_unanswered(self, role):
        raise AssertionError("realtime sends nothing again")

    # what the test reads
    def sent(self, role) -> dict[int, tuple[float, int | None]]:
        """Each step's input to ``role``: when it went, and the step it was coded from."""
        return {e[3]: (e[0], e[4]) for e in self.log if e[1] == "send" and e[2] == role}

    def events(self, name) -> list[tuple]:
        return [e for e in self.log if e[1] == name]


@pytest.fixture
def clock(monkeypatch):
    clock = Clock()
    monkeypatch.setattr("hub.realtime.time", clock)
    monkeypatch.setattr("hub.report.time", clock)  # the steps' times (LoopTimes)
    return clock


def _realtime(clock, reply_s, *overrides, n_steps=20, chores_every_s=math.inf):
    """A realtime scheduler of ``n_steps`` 10 ms steps, its port, ledger, times, standing."""
    loop = load_config(
        None, ["loop.mode=realtime", "loop.period_ms=10", "loop.realtime_priority=0", *overrides]
    ).loop
    ledger, standing = Ledger(), Standing(state="running")
    times = LoopTimes.for_run("realtime", loop.period_ms, n_steps)
    port = Port(clock, ledger, standing, reply_s, chores_every_s)
    scheduler = Realtime(port, standing, ledger, times, loop, n_steps)
    return scheduler, port, ledger, times, standing


def _run(scheduler, answers_after_window=False):
    culture = SimpleNamespace(answers_after_window=answers_after_window)
    scheduler.run(Inputs(), {"body": SimpleNamespace(), "culture": culture})


def _missing(ledger) -> dict[str, set[int]]:
    return {role: steps for role, steps in ledger.missed.items() if steps}


def test_steps_start_on_a_schedule_anchored_at_the_first_step(clock):
    scheduler, port, _, times, _ = _realtime(clock, lambda role, k: 0.003 + 0.0005 * (k % 3))
    _run(scheduler)
    start = times.t_start
    for role in ("body", "culture"):
        sent = port.sent(role)
        assert sorted(sent) == list(range(20))
        # each at its time on the schedule, whatever the replies took: nothing drifts
        assert all(t == pytest.approx(start + k * PERIOD_S) for k, (t, _) in sent.items())
    assert scheduler.k_done == 20 and times.late_steps == 0
    assert list(times.lateness_s) == [0.0] * 20
    assert times.t_stop == pytest.approx(start + 20 * PERIOD_S)  # the last step's period


def test_each_steps_inputs_are_coded_from_the_replies_of_the_step_before(clock):
    scheduler, port, *_ = _realtime(clock, lambda role, k: 0.002)
    _run(scheduler)
    for role in ("body", "culture"):
        assert {k: source for k, (_, source) in port.sent(role).items()} == {
            k: (k - 1 if k else None) for k in range(20)
        }


def test_a_reply_past_its_deadline_is_missing_and_counted_late_when_it_comes(clock):
    """The body's reply of step 5 comes 15 ms after its input, past its 10 ms deadline; that
    of step 7 never comes. The policy stands in for both (the culture's next stimulation is
    coded from nothing), and the steps keep their schedule."""
    delays = {5: 0.015, 7: None}
    scheduler, port, ledger, times, _ = _realtime(
        clock, lambda role, k: delays.get(k, 0.002) if role == "body" else 0.002
    )
    _run(scheduler)
    culture = port.sent("culture")
    assert culture[6][1] is None and culture[8][1] is None and culture[9][1] == 8
    assert ledger.late == {"body": 1}  # step 5's, when it came
    assert _missing(ledger) == {"body": {7}}  # step 7's never came
    assert times.late_steps == 2 and scheduler.k_done == 20
    assert all(t == pytest.approx(times.t_start + k * PERIOD_S) for k, (t, _) in culture.items())


def test_a_step_that_starts_over_a_quarter_period_late_is_late_and_recorded(clock):
    """The chores after step 3 take 9 ms: step 4 starts 3 ms late, more than a quarter of
    its 10 ms period."""
    scheduler, port, _, times, _ = _realtime(clock, lambda role, k: 0.004)
    port.on_tick = lambda t: setattr(port, "chore_s", 0.009 if scheduler.k_done == 4 else 0.0)
    _run(scheduler)
    assert times.lateness_s[4] == pytest.approx(0.003)
    assert times.lateness_s[4] > LATE_START_SHARE * PERIOD_S
    [(_, _, late_start)] = port.events("late_start")
    assert late_start == {"step": 4, "by_ms": pytest.approx(3.0)}
    assert times.late_steps == 1
    assert port.sent("body")[5][0] == pytest.approx(times.t_start + 5 * PERIOD_S)  # on time again


def test_the_chores_wait_for_the_slack_after_a_step_never_its_start(clock):
    """The status, the record's flushes and the observer's spikes (the port's ``tick``) fall
    due every 7 ms: they are done after each step and while waiting for the next, but never
    once that step is due: begun then, they would make it start late."""
    scheduler, port, _, times, _ = _realtime(clock, lambda role, k: 0.003, chores_every_s=0.007)
    _run(scheduler)
    start, next_step, ticks = times.t_start, 0, []
    for t, what, *details in port.log:
        if what == "send":
            next_step = details[1] + 1
        elif what == "tick" and next_step < 20:
            ticks.append((t, next_step))
    assert all(t < start + k * PERIOD_S for t, k in ticks)
    in_waits = [(t, k) for t, k in ticks if t > start + (k - 1) * PERIOD_S + 0.003 + 1e-9]
    assert len(in_waits) >= 20 // 4  # chores fell due in many waits, and were done there
    assert times.late_steps == 0


@pytest.mark.parametrize(
    "reply_s, view", [(PERIOD_S - VIEW_GUARD_S / 2, False), (PERIOD_S - 2 * VIEW_GUARD_S, True)]
)
def test_a_view_goes_after_a_step_only_with_slack_before_the_next(clock, reply_s, view):
    """Replies that leave less than ``VIEW_GUARD_S`` before the next step's start: no view
    for live displays after the step (the spikes for the burst observer go all the same);
    more, and one goes."""
    scheduler, port, *_ = _realtime(clock, lambda role, k: reply_s, n_steps=5)
    _run(scheduler)
    assert [e[2] for e in port.events("share")] == [view] * 5


def test_a_paused_run_starts_no_step_and_its_schedule_moves_on_by_the_pause(clock):
    """Paused (``ctl pause``) during step 3 for 0.5 s: no step starts meanwhile, and the
    steps after it keep the schedule, shifted by the pause."""
    scheduler, port, _, times, standing = _realtime(
        clock, lambda role, k: 0.003, chores_every_s=0.005
    )
    paused_at = []

    def control(t):
        if standing.state == "running" and scheduler.k == 3 and not paused_at:
            standing.state = "paused"
            times.pause()
            paused_at.append(t)
        elif standing.state == "paused" and t >= paused_at[0] + 0.5:
            times.resume()
            standing.state = "running"

    port.on_tick = control
    _run(scheduler)
    sent = port.sent("body")
    assert not [t for t, _ in sent.values() if paused_at[0] < t < paused_at[0] + 0.5]
    assert times.paused_s == pytest.approx(0.5, abs=0.01)
    for k in range(4, 20):
        assert sent[k][0] == pytest.approx(times.t_start + times.paused_s + k * PERIOD_S)
    assert times.late_steps == 0 and scheduler.k_done == 20


def test_a_stop_ends_the_run_before_the_next_step(clock):
    scheduler, port, _, _, standing = _realtime(clock, lambda role, k: 0.003)

    def stop(t):
        if scheduler.k_done == 6:
            standing.stop_reason = "stopped by control"

    port.on_tick = stop
    _run(scheduler)
    assert scheduler.k_done == 6 and sorted(port.sent("body")) == list(range(6))


def test_a_culture_that_answers_after_its_window_trails_by_a_step(clock):
    """A device culture replies to each window 12 ms after it began (its deadline 15 ms):
    each step starts on time, its motor command decoded from the spikes of two steps
    before, and the last step's spikes are waited for after it."""
    scheduler, port, ledger, times, _ = _realtime(
        clock, lambda role, k: 0.012 if role == "culture" else 0.002, "loop.deadline_ms=15"
    )
    _run(scheduler, answers_after_window=True)
    motors = port.sent("body")
    assert {k: source for k, (_, source) in motors.items()} == {
        k: (k - 2 if k >= 2 else None) for k in range(20)
    }
    assert all(t == pytest.approx(times.t_start + k * PERIOD_S) for k, (t, _) in motors.items())
    assert ledger.late == {} and _missing(ledger) == {} and times.late_steps == 0
    taken = [e[3] for e in port.events("taken") if e[2] == "culture"]
    assert taken == list(range(20))  # the last step's too, after it


def test_a_bodys_deadline_is_never_past_its_own_period(clock):
    """With a 15 ms deadline, a culture's reply at 12 ms is on time; a body's is not: the
    body's command of the next step cannot wait past its period."""
    scheduler, _, ledger, _, _ = _realtime(
        clock, lambda role, k: 0.012, "loop.deadline_ms=15", n_steps=2
    )
    _run(scheduler)
    assert ledger.late == {"body": 2} and "culture" not in ledger.late
