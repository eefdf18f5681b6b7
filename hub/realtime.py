"""The realtime scheduler of the hub: steps on a wall-clock schedule.

Step k starts at ``t_start + k·T`` (plus time paused), anchored at the first step so that
nothing drifts. Both inputs leave the moment a step starts (coded and encoded in the slack
of the step before); the loop's thread then takes in events until both replies are in or
the step's deadline passes, and the policy stands in for what is missing. A reply that
comes after its deadline is *late*: counted, and kept in the record as data the loop did
not use. Live burst detection is not the loop's work: the burst observer does it, in a
process of its own (hub/burst_observer.py).

The scheduler keeps its own state (the step under way, the steps done) and drives the hub
through the loop's services (:class:`hub.loop.Hub`: ``send``, ``wait_event``, ``handle``,
``next_event``, ``drain``, ``tick``, its ``ledger``, ``inputs`` and ``times``).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from hub.protocol import ROLES, Message, MotorCommand, Stimulation

if TYPE_CHECKING:
    from hub.loop import Hub

# A realtime step whose start lags its schedule by more than this share of a
# period is counted late (its window is visibly shortened).
LATE_START_SHARE = 0.25


class Realtime:
    """Steps a run on a wall-clock schedule (``loop.mode = "realtime"``).

    Attributes
    ----------
    k, k_done : int
        The step under way, and the steps over (each reply in, or stood in for).
    """

    direct = False  # replies go through the loop's thread, judged by their arrival time

    def __init__(self, hub: Hub):
        self.hub = hub
        self.k = 0
        self.k_done = 0
        self.period_s = hub.cfg.loop.period_ms / 1e3

    def run(self) -> None:
        """Steps on a wall-clock schedule; a reply missing at its deadline is replaced by policy."""
        self._steps_on_schedule()

    def rejoined(self, role: str) -> None:
        """An endpoint is back: its next step's input goes on schedule."""

    def start_of(self, k: int) -> float:
        """When step ``k`` is due to start (monotonic), given the time paused so far."""
        return self.hub.times.t_start + self.hub.times.paused_s + k * self.period_s

    def _steps_on_schedule(self) -> None:
        hub, ledger = self.hub, self.hub.ledger
        n = hub.cfg.n_steps
        # Each step's inputs are coded and encoded in the slack of the step before, so
        # that they leave the moment the step starts.
        inputs = self._encoded(hub.inputs.motor_for(0, None), hub.inputs.stim_for(0, None))
        # A device culture that answers a window once it has passed: its reply trails by a
        # step; the next step starts on time and its motor command is decoded from the
        # spikes of the step before (docs/contract.md).
        lag = int(bool(hub.descriptions["culture"].answers_after_window))
        for k in range(n):
            if not self._await_start(k):
                return
            self.k = k
            steps = {"body": k, "culture": k - lag}
            ledger.expect.update({role: max(step, 0) for role, step in steps.items()})
            t0 = time.monotonic()
            for role in ROLES:
                hub.send(role, *inputs[role])
            late = self.collect(steps, self._deadlines(steps))
            if k == 0:  # every thread that carries replies has started by now
                hub.scheduling.include_new_threads()
            prev = {role: ledger.pending[role].pop(step, None) for role, step in steps.items()}
            hub.times.step_wall_s[k] = time.monotonic() - t0
            if k + 1 < n:
                inputs = self._encoded(
                    hub.inputs.motor_for(k + 1, prev["culture"]),
                    hub.inputs.stim_for(k + 1, prev["body"]),
                )
            late_start = hub.times.lateness_s[k] > LATE_START_SHARE * self.period_s
            if late_start:  # in the record, as a reply past its deadline is (``late``)
                hub.record_event("late_start", step=k, by_ms=hub.times.lateness_s[k] * 1e3)
            hub.times.late_steps += bool(late or late_start)
            self.k_done = k + 1
            hub.tick()
        if lag:  # the last step's culture reply: in the record, and not missing
            ledger.expect["culture"] = n - 1
            steps = {"culture": n - 1}
            self.collect(steps, self._deadlines(steps))
            ledger.pending["culture"].pop(n - 1, None)

    def collect(self, steps: dict[str, int], deadlines: dict[str, float]) -> bool:
        """Take in events until each role's reply for its step is in or its deadline passes
        (a negative step: nothing owed yet).

        Returns True if a reply missed its deadline (the policy stands in for it).
        """
        hub, ledger = self.hub, self.hub.ledger
        ledger.await_replies(steps, deadlines)
        while waiting := ledger.waiting(time.monotonic()):
            self._wait(ledger.next_deadline(waiting))
        # Replies judged by when they arrived, not by when this thread got to them.
        hub.drain()
        return ledger.settle()

    @staticmethod
    def _encoded(motor: MotorCommand, stim: Stimulation) -> dict[str, tuple[Message, bytes]]:
        return {"body": (motor, motor.encode()), "culture": (stim, stim.encode())}

    def _deadlines(self, steps: dict[str, int]) -> dict[str, float]:
        """Each role's reply deadline for the step it owes: ``loop.deadline_ms`` after that
        step's start; a body always within its own period."""
        deadline_s = self.hub.cfg.loop.deadline_s
        body_s = min(deadline_s, self.period_s)
        return {
            role: self.start_of(k) + (body_s if role == "body" else deadline_s)
            for role, k in steps.items()
        }

    def _await_start(self, k: int) -> bool:
        """Handle events until step k may start; False if the run must end."""
        hub = self.hub
        while True:
            hub.drain()
            if hub.stop_reason:
                return False
            if hub.state == "paused":
                hub.next_event(time.monotonic() + 0.1)
                continue
            now = time.monotonic()
            target = self.start_of(k)
            if now >= target:
                hub.times.lateness_s[k] = now - target
                return True
            self._wait(target)

    def _wait(self, until: float) -> None:
        """Handle one event, waiting at most until ``until``. The loop's chores that fall due
        (the status, a flush of the record, the observer's spikes: ``tick``) are done here
        only if the wait ends before ``until``: at ``until`` a step starts or a deadline
        passes, and they wait for the slack after the step, where every step ends with
        them (done at a step's start they made it late)."""
        hub = self.hub
        item = hub.wait_event(until)
        if item is not None:
            hub.handle(item)
        elif time.monotonic() < until:
            hub.tick()
