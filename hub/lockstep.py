"""The lockstep scheduler of the hub: as fast as the endpoints go, pipelined.

Each input of step k+1 leaves as soon as the reply it depends on is in (the motor command
when the culture's spikes of step k arrive, the stimulation when the body's sensors of step
k arrive), so neither endpoint waits for the other's round trip; every endpoint still gets
exactly the inputs of the step-by-step scheme. Replies are taken, and the inputs that
depend on them sent, in the Zenoh thread they arrive on, under the loop's lock (a hand-over
to the loop's thread would put a wake-up on every step's critical path); so is a view for
live displays, when one is due after a step. The loop's thread handles the other events,
stands in by policy for replies owed longer than ``loop.reply_timeout_s``, publishes the
status, and sends views only while the steps stand still. Live burst detection is not the
loop's work: the burst observer does it, in a process of its own (hub/burst_observer.py).

The scheduler keeps its own state (the steps done, whether replies are taken directly,
when the loop last moved) and drives the hub through the loop's services
(:class:`hub.loop.Hub`: ``send``, ``wait_event``, ``handle``, ``tick``, ``offer_view``, its
``ledger``, ``inputs`` and ``times``).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from hub.protocol import ROLES, Message

if TYPE_CHECKING:
    from hub.loop import Hub


class Lockstep:
    """Steps a run as fast as its endpoints answer.

    Attributes
    ----------
    k, k_done : int
        The step under way, and the steps whose every reply is in (or stood in for).
    direct : bool
        Replies are being taken in the threads they arrive on (:meth:`on_reply`).
    """

    def __init__(self, hub: Hub):
        self.hub = hub
        self.k = 0
        self.k_done = 0
        self.direct = False
        self._failure: BaseException | None = None  # raised in a reply's thread
        self._last_progress = 0.0  # when the last step completed

    def run(self) -> None:
        """Step to the end of the run (or a stop). Replies are taken in the threads they
        arrive on; this thread handles the other events, stands in by policy for replies
        that do not come within ``reply_timeout_s`` and publishes the status."""
        hub, ledger = self.hub, self.hub.ledger
        n = hub.n_steps
        timeout_s = hub.cfg.loop.reply_timeout_s
        try:
            with hub.lock:
                ledger.expect.update(body=0, culture=0)
                self._last_progress = time.monotonic()
                # Direct before the first inputs go out: a reply that comes while this
                # thread is held up after them (preempted on a busy machine) then waits
                # for the lock, rather than being queued for this thread while the other
                # endpoint's reply, and the input it lets out, are taken directly: the
                # culture's next reply could be taken before its first (the record and the
                # burst observer would see step 1 before step 0, the observer count step 0
                # missing).
                self.direct = True
                hub.send("body", hub.inputs.motor_for(0, None))
                hub.send("culture", hub.inputs.stim_for(0, None))
            while True:
                with hub.lock:
                    if self._failure is not None:
                        raise self._failure
                    if hub.stop_reason or self.k_done >= n:
                        return
                    now = time.monotonic()
                    if hub.state == "paused" or hub.gone:  # gone: waiting for it to rejoin
                        self._last_progress = now
                    elif now - self._last_progress >= timeout_s:
                        self._stand_in(n)
                    until = self._last_progress + timeout_s
                item = hub.wait_event(until)
                with hub.lock:
                    if item is not None:
                        hub.handle(item)
                    self._advance(n)
                    hub.tick()
        finally:
            with hub.lock:
                self.direct = False

    def on_reply(self, item: tuple) -> None:
        """A reply, in the thread it came on: take it, send what it allows."""
        hub = self.hub
        t0 = time.perf_counter()
        with hub.lock:
            if not self.direct:  # the steps ended meanwhile: the loop's thread decides
                return hub.inbox.put(item)
            try:
                hub.handle(item)
                self._advance(hub.n_steps)
            except BaseException as exc:  # the loop's thread raises it
                self.direct, self._failure = False, exc
                hub.inbox.put(("wake",))
            hub.times.direct_busy_s += time.perf_counter() - t0

    def rejoined(self, role: str) -> None:
        """``role`` is back: the inputs it owes replies to go again; the loop waited."""
        self.hub.resend_unanswered(role)
        self._last_progress = time.monotonic()

    def _advance(self, n: int) -> None:
        """Send every input whose reply is in (unless paused or stopping), and note the
        steps completed."""
        hub, ledger = self.hub, self.hub.ledger
        if hub.state != "running" or hub.stop_reason:
            return
        expect = ledger.expect
        for role in ("culture", "body"):
            pending = ledger.pending[role]
            while pending and expect[role] in pending:
                self._pipeline(role, pending.pop(expect[role]), n)
        done = min(expect["culture"], expect["body"])
        k_done = self.k_done
        if done > k_done:
            now = time.monotonic()
            if done == k_done + 1:  # a numpy scalar store, not a slice's
                hub.times.step_wall_s[k_done] = now - self._last_progress
            else:
                hub.times.step_wall_s[k_done:done] = (now - self._last_progress) / (done - k_done)
            self._last_progress = now
            self.k_done = self.k = done
            if done >= n:
                hub.inbox.put(("wake",))
            hub.offer_view(now)

    def _stand_in(self, n: int) -> None:
        """No reply for ``reply_timeout_s``: the policy stands in for each reply owed (an
        input that waits on another reply is not owed yet)."""
        ledger = self.hub.ledger
        expect = ledger.expect
        owed = [r for r in ROLES if ledger.last_sent.get(r, -1) >= expect[r] < n]
        for role in owed:
            ledger.miss(role, expect[role])
            self._pipeline(role, None, n)
        self._last_progress = time.monotonic()
        self._advance(n)

    def _pipeline(self, role: str, reply: Message | None, n: int) -> None:
        """Take the reply of ``role`` for its expected step k; send the other side step k+1."""
        hub, expect = self.hub, self.hub.ledger.expect
        k = expect[role]
        expect[role] = k + 1
        if k + 1 < n and not hub.stop_reason:
            if role == "culture":
                hub.send("body", hub.inputs.motor_for(k + 1, reply))
            else:
                hub.send("culture", hub.inputs.stim_for(k + 1, reply))
