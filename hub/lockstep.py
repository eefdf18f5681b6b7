"""The lockstep scheduler of the hub: as fast as the endpoints go, pipelined.

Each input of step k+1 leaves as soon as the reply it depends on is in (the motor command
when the culture's spikes of step k arrive, the stimulation when the body's sensors of step
k arrive), so neither endpoint waits for the other's round trip; every endpoint still gets
exactly the inputs of the step-by-step scheme. During the steps each reply is taken, and
the inputs that depend on it sent, in the Zenoh thread it arrives on, under the
scheduler's lock (a hand-over to the loop's thread would put a wake-up on every step's
critical path); so are the spikes for the burst observer and a view for live displays,
when due after a step. The loop's thread handles the other events under the same lock,
stands in by policy for replies owed longer than ``loop.reply_timeout_s``, does the
loop's chores, and sends views only while the steps stand still.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING

from hub.steps import Scheduler

if TYPE_CHECKING:
    from hub.policy import InputPolicy
    from hub.protocol import Description, Message
    from hub.steps import LoopPort

# The loop's thread sends a view only once the steps stood still this long past its time
# (paused, an endpoint awaited): woken at the view rate, it took the lock from the replies
# thirty times a second (docs/measurements/dashboard-cost.md).
VIEW_STALL_S = 0.1


class Lockstep(Scheduler):
    """Steps a run as fast as its endpoints answer.

    Parameters
    ----------
    port : LoopPort
        The hub's services.
    *parts
        The rest of :class:`~hub.steps.Scheduler`'s parameters (standing, ledger, times,
        loop, n_steps).

    Attributes
    ----------
    direct : bool
        Replies are being taken in the threads they arrive on (:meth:`deliver`).
    """

    def __init__(self, port: LoopPort, *parts) -> None:
        super().__init__(port, *parts)
        self.direct = False
        self._lock = threading.Lock()  # held by whatever touches the loop's state
        self._handle, self._post = port.handle, port.post
        self._failure: BaseException | None = None  # raised in a reply's thread
        self._pipe: Pipeline | None = None  # the run's, once it runs

    def deliver(self, item: tuple) -> None:
        """An event from the bus, on its thread: a reply during the steps is taken here and
        the inputs it lets out are sent; anything else goes to the loop's thread."""
        if not (self.direct and item[0] in ("rx", "refused")):
            return self._post(item)
        t0 = time.perf_counter()
        with self._lock:
            if not self.direct:  # the steps ended meanwhile: the loop's thread decides
                return self._post(item)
            try:
                self._handle(item)
                self._stepped(self._pipe.advance())
            except BaseException as exc:  # the loop's thread raises it
                self.direct, self._failure = False, exc
                self._post(("wake",))
            self._times.direct_busy_s += time.perf_counter() - t0

    def run(self, inputs: InputPolicy, descriptions: dict[str, Description]) -> None:
        """Step to the end of the run (or a stop)."""
        port, standing, lock = self._port, self._standing, self._lock
        timeout_s = self._loop.reply_timeout_s
        self._pipe = pipe = Pipeline(
            port.send, inputs, standing, self._ledger, self._times, self._n
        )
        self._times.start()
        try:
            with lock:
                # Direct before the first inputs go out: a reply that comes while this thread
                # is held up after them then waits for the lock, instead of being queued here
                # while later replies are taken directly (step 1 taken before step 0).
                self.direct = True
                pipe.start()
            while True:
                with lock:
                    if self._failure is not None:
                        raise self._failure
                    if standing.stop_reason or self.k_done >= self._n:
                        return
                    if standing.state == "paused" or standing.awaited:
                        pipe.last_progress = time.monotonic()  # the reply timeout waits too
                    elif time.monotonic() - pipe.last_progress >= timeout_s:
                        self._stepped(pipe.stand_in())
                    view_at = port.view_due_at + VIEW_STALL_S
                item = port.wait_event(min(pipe.last_progress + timeout_s, view_at))
                with lock:
                    if item is not None:
                        port.handle(item)
                    self._stepped(pipe.advance())
                    port.tick()
                    if (now := time.monotonic()) >= port.view_due_at + VIEW_STALL_S:
                        port.share(now)
        finally:
            with lock:
                self.direct = False
            self._times.stop()

    def rejoined(self, role: str) -> None:
        """``role`` is back: the inputs it owes replies to go again; the loop waited."""
        self._port.resend_unanswered(role)
        self._pipe.last_progress = time.monotonic()

    def _stepped(self, done: int) -> None:
        """The steps completed are now ``done``: the run's end is woken to, and live
        displays are shared what is new."""
        if done > self.k_done:
            self.k_done = self.k = done
            if done >= self._n:
                self._post(("wake",))
            self._port.share(self._pipe.last_progress)


class Pipeline:
    """Lockstep's order of inputs, pipelined: each input of step k+1 goes as soon as the
    reply it depends on is in; the steps completed, and how long each took.

    Parameters
    ----------
    send : callable
        ``send(role, message)``: an input to an endpoint.
    inputs : InputPolicy
        Makes each input from the reply it depends on (None: the policy stands in).
    standing : Standing
        Where the run stands: no input goes while paused or stopping.
    ledger : Ledger
        The replies in (``pending``), the step each role owes (``expect``).
    times : LoopTimes
        Where each step's wall time goes.
    n_steps : int
        The run's steps.

    Attributes
    ----------
    k_done : int
        The steps completed (both replies taken or stood in for).
    last_progress : float
        When (monotonic) the last step completed; the reply timeout counts from it.
    """

    def __init__(self, send, inputs: InputPolicy, standing, ledger, times, n_steps: int):
        self._send, self._standing, self._ledger = send, standing, ledger
        self._times, self._n = times, n_steps
        # the input each role's reply lets out: the culture's spikes, the body's motor
        # command; the body's sensors, the culture's stimulation
        self._next = {"culture": ("body", inputs.motor_for), "body": ("culture", inputs.stim_for)}
        self.k_done, self.last_progress = 0, 0.0

    def start(self) -> None:
        """Step 0's inputs go (the body's first)."""
        self._ledger.expect.update(body=0, culture=0)
        self.last_progress = time.monotonic()
        for role, code in self._next.values():
            self._send(role, code(0, None))

    def advance(self) -> int:
        """Send every input whose reply is in (unless paused or stopping); the steps
        completed."""
        standing, ledger = self._standing, self._ledger
        if standing.state != "running" or standing.stop_reason:
            return self.k_done
        expect = ledger.expect
        for role in ("culture", "body"):
            pending = ledger.pending[role]
            while pending and expect[role] in pending:
                self._take(role, pending.pop(expect[role]))
        done, k_done = min(expect["culture"], expect["body"]), self.k_done
        if done > k_done:
            now = time.monotonic()
            self._times.steps_took(k_done, done, now - self.last_progress)
            self.last_progress, self.k_done = now, done
        return done

    def stand_in(self) -> int:
        """No reply for the timeout: the policy stands in for each reply owed (an input
        that waits on another reply is not owed yet); the steps completed."""
        ledger = self._ledger
        for role in ledger.owed(self._n):
            ledger.miss(role, ledger.expect[role])
            self._take(role, None)
        self.last_progress = time.monotonic()
        return self.advance()

    def _take(self, role: str, reply: Message | None) -> None:
        """Take the reply of ``role`` for its expected step k; send the other side step k+1."""
        expect = self._ledger.expect
        k = expect[role] = expect[role] + 1  # the step whose input the reply lets out
        if k < self._n and not self._standing.stop_reason:
            other, code = self._next[role]
            self._send(other, code(k, reply))
