"""The lockstep scheduler (hub/lockstep.py): which input it sends when, given the replies
that come, on which thread it takes them, and what it does when one does not come.

The scheduler sees the hub only through its services (:class:`hub.steps.LoopPort`); a port
of the test's plays them: it records what the scheduler sends and does, judges each reply
with a real ledger, and keeps the loop thread's events in a queue as the hub does. Replies
are delivered as Zenoh delivers them, on a thread other than the loop's: by endpoints of
the test's that answer each input (or not), or by the test itself. No bus, no hub.
"""

from __future__ import annotations

import math
import queue
import threading
import time

import numpy as np

from hub.config import load_config
from hub.ledger import Ledger
from hub.lockstep import VIEW_STALL_S, Lockstep, Pipeline
from hub.report import LoopTimes
from hub.steps import Standing
from tests.harness import wait_for
from tests.hub.scheduler_parts import Input, Inputs, Reply


def rx(role: str, step: int) -> tuple:
    """A reply event as the hub's link delivers it."""
    return ("rx", role, Reply(step), time.time_ns(), time.monotonic())


class Port:
    """The hub as the lockstep scheduler sees it (hub.steps.LoopPort), with endpoints that
    answer each input on a thread of their own when ``answers(input)`` says so."""

    def __init__(self, ledger: Ledger, answers=lambda message: False):
        self.ledger, self.answers = ledger, answers
        self.scheduler: Lockstep | None = None
        self.inbox: queue.SimpleQueue = queue.SimpleQueue()  # the loop thread's events
        self.sent: list[Input] = []
        self.taken: list[tuple[str, int, str]] = []  # (role, step, the thread it was taken on)
        self.shared: list[str] = []  # the thread each view (and spikes) went from
        self.resent: list[str] = []
        self.view_due_at = math.inf
        self.fail_on: tuple[str, int] | None = None  # a reply whose taking raises
        self._to_answer: queue.SimpleQueue = queue.SimpleQueue()

    def serve(self, scheduler: Lockstep) -> None:
        """The endpoints answer on a thread of their own, as the link's callback does."""
        self.scheduler = scheduler
        threading.Thread(target=self._endpoints, name="endpoints", daemon=True).start()

    def _endpoints(self) -> None:
        while (message := self._to_answer.get()) is not None:
            self.scheduler.deliver(rx(message.role, message.step))

    def close(self) -> None:
        self._to_answer.put(None)

    # LoopPort
    def send(self, role, message, raw=None):
        self.ledger.sent(role, message.step)
        self.sent.append(message)
        if self.answers(message):
            self._to_answer.put(message)

    def resend_unanswered(self, role):
        self.resent.append(role)

    def handle(self, item):
        if item[0] != "rx":
            return
        _, role, reply, _, arrival = item
        if (role, reply.step) == self.fail_on:
            raise ValueError(f"a {role} reply that cannot be taken")
        self.taken.append((role, reply.step, threading.current_thread().name))
        self.ledger.judge(role, reply, arrival, running=True)

    def wait_event(self, until):
        try:
            return self.inbox.get(timeout=max(min(until - time.monotonic(), 1.0), 0.0))
        except queue.Empty:
            return None

    def drain(self):
        raise AssertionError("lockstep takes its events one by one")

    def post(self, item):
        self.inbox.put(item)

    def tick(self):
        pass

    def share(self, now, *, view=True):
        self.shared.append(threading.current_thread().name)

    def record_event(self, name, **details):
        pass

    # what the test reads
    def inputs_of(self, role) -> dict[int, int | None]:
        """Each step's input to ``role``: the step of the reply it was coded from."""
        return {m.step: m.source for m in self.sent if m.role == role}


class Run:
    """A lockstep scheduler of ``n_steps`` running on a thread of its own (the loop's)."""

    def __init__(self, n_steps=20, answers=lambda message: False, reply_timeout_s=10.0):
        loop = load_config(None, [f"loop.reply_timeout_s={reply_timeout_s}"]).loop
        self.ledger, self.standing = Ledger(), Standing(state="running")
        self.times = LoopTimes.for_run("lockstep", loop.period_ms, n_steps)
        self.port = Port(self.ledger, answers)
        self.scheduler = Lockstep(self.port, self.standing, self.ledger, self.times, loop, n_steps)
        self.port.serve(self.scheduler)
        self.failure: BaseException | None = None
        self.thread = threading.Thread(target=self._run, name="loop")

    def _run(self):
        try:
            self.scheduler.run(Inputs(), {})
        except BaseException as exc:
            self.failure = exc

    def __enter__(self):
        self.thread.start()
        wait_for(lambda: len(self.port.sent) >= 2)  # the first inputs went
        return self

    def __exit__(self, *exc):
        if self.thread.is_alive():
            self.standing.stop_reason = "the test is over"
            self.port.post(("wake",))
        self.thread.join(10)
        self.port.close()

    def ended(self) -> bool:
        self.thread.join(10)
        return not self.thread.is_alive()

    def deliver(self, role, step):
        """A reply, delivered on the test's thread (a thread of Zenoh's)."""
        self.scheduler.deliver(rx(role, step))


def test_every_endpoint_gets_the_inputs_of_the_step_by_step_scheme():
    """The body's command of step k is decoded from the culture's spikes of step k-1, the
    culture's stimulation coded from the body's sensors of step k-1; step 0's from nothing."""
    with Run(answers=lambda message: True) as run:
        assert run.ended() and run.failure is None
    assert run.scheduler.k_done == 20
    for role in ("body", "culture"):
        assert run.port.inputs_of(role) == {k: (k - 1 if k else None) for k in range(20)}
    assert len(run.port.sent) == 40  # each once
    assert not any(math.isnan(s) or s < 0 for s in run.times.step_wall_s)


def test_each_input_leaves_as_soon_as_the_reply_it_depends_on_is_in():
    """Neither endpoint waits for the other's round trip: the culture's spikes of step 0
    let the body's command of step 1 out before the body's own reply of step 0 is in."""
    with Run() as run:
        run.deliver("culture", 0)
        assert run.port.inputs_of("body") == {0: None, 1: 0}
        assert run.port.inputs_of("culture") == {0: None}  # it waits on the body's sensors
        assert run.scheduler.k_done == 0
        run.deliver("body", 0)
        assert run.port.inputs_of("culture") == {0: None, 1: 0}
        assert run.scheduler.k_done == 1


def test_during_the_steps_a_reply_is_taken_on_the_thread_it_comes_on():
    """A reply is taken, and what it lets out sent, by the thread that received it: a
    hand-over to the loop's thread would put a wake-up on every step's critical path.
    Before and after the steps, events go to the loop's thread."""
    run = Run(n_steps=1)
    run.deliver("body", 0)  # before the steps: queued for the loop's thread
    assert run.port.inbox.get_nowait()[:3] == ("rx", "body", Reply(0))
    with run:
        run.deliver("culture", 0)
        run.deliver("body", 0)
        assert run.ended()
    assert run.port.taken == [("culture", 0, "MainThread"), ("body", 0, "MainThread")]
    run.deliver("culture", 1)  # after the steps: queued again, not taken
    assert run.port.inbox.get_nowait()[:3] == ("rx", "culture", Reply(1))
    assert len(run.port.taken) == 2


def test_a_reply_owed_past_the_reply_timeout_is_stood_in_for_by_the_policy():
    """The body never answers step 3: after ``reply_timeout_s`` its reply is counted
    missing and the culture's stimulation of step 4 is coded from nothing; the steps go on
    to the end. An input that waits on another reply was not owed: nothing else missing."""
    answers = lambda message: (message.role, message.step) != ("body", 3)  # noqa: E731
    with Run(n_steps=8, answers=answers, reply_timeout_s=0.05) as run:
        assert run.ended() and run.failure is None
    assert run.scheduler.k_done == 8
    assert {role: steps for role, steps in run.ledger.missed.items() if steps} == {"body": {3}}
    assert run.port.inputs_of("culture")[4] is None
    assert run.port.inputs_of("culture")[5] == 4


def test_while_paused_no_input_goes_and_the_reply_timeout_waits():
    with Run(reply_timeout_s=0.05) as run:
        run.standing.state = "paused"  # ``ctl pause``, handled by the loop's thread
        run.deliver("culture", 0)
        time.sleep(0.2)  # four reply timeouts
        assert run.port.inputs_of("body") == {0: None}
        assert not any(run.ledger.missed.values())
        run.standing.state = "running"  # ``ctl resume``
        run.port.post(("wake",))
        wait_for(lambda: 1 in run.port.inputs_of("body"))


def test_an_endpoint_awaited_back_holds_the_reply_timeout_and_gets_its_inputs_again():
    """A body that vanished may rejoin (``policy.rejoin_s``): the steps wait for it, and
    once it is back it is sent again the inputs it has not answered."""
    with Run(reply_timeout_s=0.05) as run:
        run.standing.awaited["body"] = (time.monotonic(), 0)
        run.deliver("culture", 0)
        time.sleep(0.2)
        assert not any(run.ledger.missed.values())
        del run.standing.awaited["body"]
        run.scheduler.rejoined("body")
        assert run.port.resent == ["body"]
        run.deliver("body", 0)
        run.deliver("body", 1)
        assert run.scheduler.k_done == 1 and not any(run.ledger.missed.values())


def test_a_stop_ends_the_steps_after_the_step_under_way():
    with Run() as run:
        run.deliver("culture", 0)
        run.standing.stop_reason = "stopped by control"
        run.port.post(("wake",))
        assert run.ended() and run.failure is None
        run.deliver("body", 0)  # the steps are over: queued for the loop's thread
    assert run.scheduler.k_done == 0
    assert run.port.inputs_of("culture") == {0: None}


def test_a_reply_that_cannot_be_taken_ends_the_run_from_the_loops_thread():
    """Whatever its thread raises while taking a reply, the loop's thread raises (the hub
    ends the run as a fault there)."""
    with Run() as run:
        run.port.fail_on = ("culture", 1)
        run.deliver("culture", 0)
        run.deliver("body", 0)
        run.deliver("culture", 1)
        assert run.ended()
    assert isinstance(run.failure, ValueError)
    assert not run.scheduler.direct


def test_views_go_after_each_step_and_from_the_loops_thread_only_once_the_steps_stand_still():
    """A view (and the burst observer's spikes) goes from the reply's thread after each
    step; the loop's thread sends one only once the steps stood still ``VIEW_STALL_S`` past
    its time (so that it does not take the lock from the replies at the view rate)."""
    with Run() as run:
        run.deliver("culture", 0)
        run.deliver("body", 0)
        assert run.port.shared == ["MainThread"]  # after step 0, on the reply's thread
        run.port.view_due_at = due = time.monotonic()
        run.port.post(("wake",))  # the loop's thread looks: not yet
        time.sleep(VIEW_STALL_S / 2)
        assert run.port.shared == ["MainThread"]
        wait_for(lambda: "loop" in run.port.shared, timeout_s=2)
        assert time.monotonic() >= due + VIEW_STALL_S


# ------------------------------------------------------------------ the pipeline alone


def pipeline(n_steps: int = 3) -> tuple[Pipeline, list[Input], Ledger, LoopTimes, Standing]:
    """A pipeline with nothing between it and the test: no thread, no lock, no port."""
    sent: list[Input] = []
    ledger, standing = Ledger(), Standing(state="running")
    times = LoopTimes.for_run("lockstep", 10.0, n_steps)

    def send(role, message):
        ledger.sent(role, message.step)
        sent.append(message)

    return Pipeline(send, Inputs(), standing, ledger, times, n_steps), sent, ledger, times, standing


def reply_in(ledger: Ledger, role: str, step: int) -> None:
    ledger.pending[role][step] = Reply(step)


def test_the_pipeline_sends_each_input_once_the_reply_it_is_coded_from_is_in():
    pipe, sent, ledger, times, _ = pipeline()
    pipe.start()
    assert sent == [Input("body", 0, None), Input("culture", 0, None)]
    reply_in(ledger, "culture", 0)
    assert pipe.advance() == 0  # the body's reply of step 0 is still owed
    assert sent[2:] == [Input("body", 1, 0)]  # the motor command, from the culture's spikes
    reply_in(ledger, "body", 0)
    assert pipe.advance() == 1 and pipe.k_done == 1
    assert sent[3:] == [Input("culture", 1, 0)]
    assert times.step_wall_s[0] >= 0 and np.isnan(times.step_wall_s[1])


def test_the_pipeline_sends_nothing_while_paused_or_stopping():
    for stand in (dict(state="paused"), dict(stop_reason="stopped by control")):
        pipe, sent, ledger, _, standing = pipeline()
        pipe.start()
        for name, value in stand.items():
            setattr(standing, name, value)
        reply_in(ledger, "culture", 0)
        reply_in(ledger, "body", 0)
        assert pipe.advance() == 0 and len(sent) == 2


def test_the_pipeline_stands_in_only_for_replies_whose_input_went_out():
    pipe, sent, ledger, _, _ = pipeline()
    pipe.start()
    reply_in(ledger, "culture", 0)
    pipe.advance()  # the body's step 1 went; the culture's step 1 waits on the body's reply
    assert pipe.stand_in() == 1
    assert dict(ledger.missed) == {"body": {0}}  # the culture owed nothing: not missed
    assert sent[-1] == Input("culture", 1, None)  # coded with the policy's stand-in


def test_the_pipeline_sends_no_input_past_the_runs_last_step():
    pipe, sent, ledger, _, _ = pipeline(n_steps=1)
    pipe.start()
    reply_in(ledger, "culture", 0)
    reply_in(ledger, "body", 0)
    assert pipe.advance() == 1 and len(sent) == 2
