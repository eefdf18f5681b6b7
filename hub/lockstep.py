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

from hub.protocol import ROLES, Message
from hub.steps import Scheduler

if TYPE_CHECKING:
    from hub.policy import InputPolicy
    from hub.protocol import Description
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
        self._last_progress = 0.0  # when the last step completed

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
                self._advance()
            except BaseException as exc:  # the loop's thread raises it
                self.direct, self._failure = False, exc
                self._post(("wake",))
            self._times.direct_busy_s += time.perf_counter() - t0

    def run(self, inputs: InputPolicy, descriptions: dict[str, Description]) -> None:
        """Step to the end of the run (or a stop)."""
        port, standing, lock = self._port, self._standing, self._lock
        timeout_s = self._loop.reply_timeout_s
        self._send, self._share = port.send, port.share
        self._motor_for, self._stim_for = inputs.motor_for, inputs.stim_for
        self._times.start()
        try:
            with lock:
                self._ledger.expect.update(body=0, culture=0)
                self._last_progress = time.monotonic()
                # Direct before the first inputs go out: a reply that comes while this thread
                # is held up after them then waits for the lock, instead of being queued here
                # while later replies are taken directly (step 1 taken before step 0).
                self.direct = True
                self._send("body", self._motor_for(0, None))
                self._send("culture", self._stim_for(0, None))
            while True:
                with lock:
                    if self._failure is not None:
                        raise self._failure
                    if standing.stop_reason or self.k_done >= self._n:
                        return
                    now = time.monotonic()
                    if standing.state == "paused" or standing.awaited:
                        self._last_progress = now  # the reply timeout waits with the steps
                    elif now - self._last_progress >= timeout_s:
                        self._stand_in()
                    view_at = port.view_due_at + VIEW_STALL_S
                item = port.wait_event(min(self._last_progress + timeout_s, view_at))
                with lock:
                    if item is not None:
                        port.handle(item)
                    self._advance()
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
        self._last_progress = time.monotonic()

    def _advance(self) -> None:
        """Send every input whose reply is in (unless paused or stopping), and note the
        steps completed."""
        standing, ledger = self._standing, self._ledger
        if standing.state != "running" or standing.stop_reason:
            return
        expect = ledger.expect
        for role in ("culture", "body"):
            pending = ledger.pending[role]
            while pending and expect[role] in pending:
                self._pipeline(role, pending.pop(expect[role]))
        done, k_done = min(expect["culture"], expect["body"]), self.k_done
        if done > k_done:
            now = time.monotonic()
            if done == k_done + 1:  # a numpy scalar store, not a slice's
                self._times.step_wall_s[k_done] = now - self._last_progress
            else:
                self._times.step_wall_s[k_done:done] = (now - self._last_progress) / (done - k_done)
            self._last_progress = now
            self.k_done = self.k = done
            if done >= self._n:
                self._post(("wake",))
            self._share(now)

    def _stand_in(self) -> None:
        """No reply for ``reply_timeout_s``: the policy stands in for each reply owed (an
        input that waits on another reply is not owed yet)."""
        ledger = self._ledger
        expect = ledger.expect
        for role in [r for r in ROLES if ledger.last_sent.get(r, -1) >= expect[r] < self._n]:
            ledger.miss(role, expect[role])
            self._pipeline(role, None)
        self._last_progress = time.monotonic()
        self._advance()

    def _pipeline(self, role: str, reply: Message | None) -> None:
        """Take the reply of ``role`` for its expected step k; send the other side step k+1."""
        expect = self._ledger.expect
        k = expect[role]
        expect[role] = k + 1
        if k + 1 < self._n and not self._standing.stop_reason:
            if role == "culture":
                self._send("body", self._motor_for(k + 1, reply))
            else:
                self._send("culture", self._stim_for(k + 1, reply))
