"""The realtime scheduler of the hub: steps on a wall-clock schedule.

Step k starts at ``t_start + k·T`` (plus time paused), anchored at the first step so that
nothing drifts. Both inputs leave the moment a step starts (coded and encoded in the slack
of the step before); the loop's thread then takes in events until both replies are in or
the step's deadline passes, and the policy stands in for what is missing. A reply that
comes after its deadline is *late*: counted, and kept in the record as data the loop did
not use. For the steps the hub's threads run under the kernel's real-time scheduler
(``loop.realtime_priority``; docs/architecture.md, "The loop").
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

from hub.protocol import ROLES
from hub.scheduling import raise_threads, restore_threads
from hub.steps import Scheduler

if TYPE_CHECKING:
    from hub.policy import InputPolicy
    from hub.protocol import Description, Message
    from hub.steps import LoopPort

log = logging.getLogger(__name__)

# A step whose start lags its schedule by more than this share of a period is counted
# late (its window is visibly shortened).
LATE_START_SHARE = 0.25
# A view for live displays is built after a step only this long or more before the next
# step's start (else after a later step), so that it never delays a step.
VIEW_GUARD_S = 1e-3


class Realtime(Scheduler):
    """Steps a run on a wall-clock schedule.

    Parameters
    ----------
    port : LoopPort
        The hub's services.
    *parts
        The rest of :class:`~hub.steps.Scheduler`'s parameters (standing, ledger, times,
        loop, n_steps).
    """

    def __init__(self, port: LoopPort, *parts) -> None:
        super().__init__(port, *parts)
        self.deliver = port.post  # replies go to the loop's thread, judged by their arrival
        self._period_s = period_s = self._loop.period_ms / 1e3
        deadline_s = self._loop.deadline_s  # after a step's start; a body's within its period
        self._deadline_s = {"body": min(deadline_s, period_s), "culture": deadline_s}

    def run(self, inputs: InputPolicy, descriptions: dict[str, Description]) -> None:
        """Step on schedule to the end of the run (or a stop), the hub's threads raised."""
        priority = self._loop.realtime_priority
        self.scheduling = got = raise_threads(priority)
        if got.policy != "fifo" and priority:
            log.warning("realtime steps under the ordinary scheduler: %s", got.reason)
        self._port.record_event("scheduling", **got.to_dict())
        self._times.start()  # the schedule starts now: the set-up is not step 0's lateness
        try:
            # A device culture that answers a window once it has passed: its reply trails by
            # a step; the next step starts on time and its motor command is decoded from the
            # spikes of the step before (docs/contract.md).
            self._steps(inputs, int(bool(descriptions["culture"].answers_after_window)))
        finally:
            restore_threads(got)
            self._times.stop(self.start_of(self.k_done))

    def start_of(self, k: int) -> float:
        """When step ``k`` is due to start (monotonic), given the time paused so far."""
        return self._times.t_start + self._times.paused_s + k * self._period_s

    def _steps(self, inputs: InputPolicy, lag: int) -> None:
        port, ledger, times, n = self._port, self._ledger, self._times, self._n
        # Each step's inputs are coded and encoded in the slack of the step before.
        sent = _encoded(inputs, 0, None, None)
        for k in range(n):
            if not self._await_start(k):
                return
            self.k = k
            steps = {"body": k, "culture": k - lag}
            ledger.expect.update({role: max(step, 0) for role, step in steps.items()})
            t0 = time.monotonic()
            for role in ROLES:
                port.send(role, *sent[role])
            late = self._collect(steps)
            if k == 0:  # every thread that carries replies has started by now
                self.scheduling.include_new_threads()
            prev = {role: ledger.pending[role].pop(step, None) for role, step in steps.items()}
            times.step_wall_s[k] = time.monotonic() - t0
            if k + 1 < n:
                sent = _encoded(inputs, k + 1, prev["culture"], prev["body"])
            late_start = times.lateness_s[k] > LATE_START_SHARE * self._period_s
            if late_start:  # in the record, as a reply past its deadline is (``late``)
                port.record_event("late_start", step=k, by_ms=times.lateness_s[k] * 1e3)
            times.late_steps += bool(late or late_start)
            self.k_done = k + 1
            self._chores()
        if lag:  # the last step's culture reply: in the record, and not missing
            ledger.expect["culture"] = n - 1
            self._collect({"culture": n - 1})
            ledger.pending["culture"].pop(n - 1, None)

    def _collect(self, steps: dict[str, int]) -> bool:
        """Take in events until each role's reply for its step is in or its deadline passes
        (a negative step: nothing owed yet); True if a reply missed its deadline."""
        ledger = self._ledger
        deadlines = {role: self.start_of(k) + self._deadline_s[role] for role, k in steps.items()}
        ledger.await_replies(steps, deadlines)
        while waiting := ledger.waiting(time.monotonic()):
            self._wait(ledger.next_deadline(waiting))
        self._port.drain()  # replies judged by when they arrived, not when looked at
        return ledger.settle()

    def _await_start(self, k: int) -> bool:
        """Handle events until step k may start; False if the run must end."""
        port, standing = self._port, self._standing
        while True:
            port.drain()
            if standing.stop_reason:
                return False
            if standing.state == "paused":  # no step is due: the chores may go at any time
                self._wait(time.monotonic() + 0.1, paused=True)
                continue
            now = time.monotonic()
            target = self.start_of(k)
            if now >= target:
                self._times.lateness_s[k] = now - target
                return True
            self._wait(target)

    def _wait(self, until: float, *, paused: bool = False) -> None:
        """Handle one event, waiting at most until ``until``. The chores that fall due are
        done here only if the wait ends before ``until``: at ``until`` a step starts or a
        deadline passes, and they wait for the slack after the step (done at a step's
        start they made it late)."""
        item = self._port.wait_event(until)
        if item is not None:
            self._port.handle(item)
        elif paused or time.monotonic() < until:
            self._chores()

    def _chores(self) -> None:
        """The loop's chores, the burst observer's spikes and, if it cannot delay the next
        step's start, a view for live displays."""
        self._port.tick()
        now = time.monotonic()
        running = self._standing.state == "running"
        self._port.share(now, view=not running or self.start_of(self.k_done) - now >= VIEW_GUARD_S)


def _encoded(
    inputs: InputPolicy, k: int, culture_reply: Message | None, body_reply: Message | None
) -> dict[str, tuple[Message, bytes]]:
    """Each role's input of step ``k`` with its encoding, ready to go at the step's start
    (made from the replies of the step before; None: stood in for)."""
    motor, stim = inputs.motor_for(k, culture_reply), inputs.stim_for(k, body_reply)
    return {"body": (motor, motor.encode()), "culture": (stim, stim.encode())}
