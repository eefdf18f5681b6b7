"""The realtime scheduler of the hub: steps on a wall-clock schedule.

Step k starts at ``t_start + k·T`` (plus time paused), anchored at the first step so that
nothing drifts. Both inputs leave the moment a step starts (coded and encoded in the slack
of the step before); the loop's thread then takes in events until both replies are in or
the step's deadline passes, and the policy stands in for what is missing. A reply that
comes after its deadline is *late*: counted, and kept in the record as data the loop did
not use. Live burst analysis runs on a thread of its own in the rest of each step.

A mixin of :class:`hub.loop.Hub`: it works on the hub's state, under the rules written
there.
"""

from __future__ import annotations

import time

from hub.live import BackgroundLiveBursts
from hub.protocol import ROLES, Message, MotorCommand, Stimulation

# A realtime step whose start lags its schedule by more than this share of a
# period is counted late (its window is visibly shortened).
LATE_START_SHARE = 0.25
# Realtime live analysis stops this share of a period before the next step's start.
LIVE_GUARD_SHARE = 0.1


class RealtimeSteps:
    """The realtime steps of :class:`~hub.loop.Hub`."""

    def _steps_realtime(self) -> None:
        """Steps on a wall-clock schedule; a reply missing at its deadline is replaced by policy."""
        live = self.live
        background = BackgroundLiveBursts(live, self.scheduling) if live is not None else None
        try:
            self._steps_on_schedule(background)
        finally:
            if background is not None:
                self._record_network_bursts(background.close())

    def _steps_on_schedule(self, background: BackgroundLiveBursts | None) -> None:
        period_s = self.cfg.loop.period_ms / 1e3
        n = self.cfg.n_steps
        guard_s = LIVE_GUARD_SHARE * period_s
        # Each step's inputs are coded and encoded in the slack of the step before, so
        # that they leave the moment the step starts.
        inputs = self._encoded(self.inputs.motor_for(0, None), self.inputs.stim_for(0, None))
        # A device culture that answers a window once it has passed: its reply trails by a
        # step; the next step starts on time and its motor command is decoded from the
        # spikes of the step before (docs/contract.md).
        lag = int(bool(self.descriptions["culture"].answers_after_window))
        for k in range(n):
            if not self._await_start(k, period_s):
                return
            self.k = k
            steps = {"body": k, "culture": k - lag}
            self.expect = {role: max(step, 0) for role, step in steps.items()}
            t0 = time.monotonic()
            for role in ROLES:
                self._send(role, *inputs[role])
            late = self._collect(steps, self._deadlines(steps, period_s))
            if k == 0:  # every thread that carries replies has started by now
                self.scheduling.include_new_threads()
            prev = {role: self.pending[role].pop(step, None) for role, step in steps.items()}
            self.times.step_wall_s[k] = time.monotonic() - t0
            if k + 1 < n:
                inputs = self._encoded(
                    self.inputs.motor_for(k + 1, prev["culture"]),
                    self.inputs.stim_for(k + 1, prev["body"]),
                )
            self.times.late_steps += bool(
                late or self.times.lateness_s[k] > LATE_START_SHARE * period_s
            )
            self.k_done = k + 1
            if background is not None:
                if prev["culture"] is not None:
                    # Analysis may use what is left of this step, not the next one's start.
                    background.add(prev["culture"], self._scheduled(k + 1, period_s) - guard_s)
                self._record_network_bursts(background.completed())
            self._tick()
        if lag:  # the last step's culture reply: in the record, and not missing
            self.expect["culture"] = n - 1
            steps = {"culture": n - 1}
            self._collect(steps, self._deadlines(steps, period_s))
            last = self.pending["culture"].pop(n - 1, None)
            if background is not None and last is not None:
                background.add(last, time.monotonic() + guard_s)

    @staticmethod
    def _encoded(motor: MotorCommand, stim: Stimulation) -> dict[str, tuple[Message, bytes]]:
        return {"body": (motor, motor.encode()), "culture": (stim, stim.encode())}

    def _deadlines(self, steps: dict[str, int], period_s: float) -> dict[str, float]:
        """Each role's reply deadline for the step it owes: ``loop.deadline_ms`` after that
        step's start; a body always within its own period."""
        deadline_s = self.cfg.loop.deadline_s
        return {
            role: self._scheduled(k, period_s)
            + (min(deadline_s, period_s) if role == "body" else deadline_s)
            for role, k in steps.items()
        }

    def _scheduled(self, k: int, period_s: float) -> float:
        return self.times.t_start + self._paused_s + k * period_s

    def _await_start(self, k: int, period_s: float) -> bool:
        """Handle events until step k may start; False if the run must end."""
        realtime = self.cfg.loop.mode == "realtime"
        while True:
            self._drain()
            if self._stop_reason:
                return False
            if self.state == "paused":
                self._next_event(time.monotonic() + 0.1)
                continue
            now = time.monotonic()
            target = self._scheduled(k, period_s) if realtime else now
            if now >= target:
                if realtime:
                    self.times.lateness_s[k] = now - target
                return True
            self._next_event(target)

    def _collect(self, steps: dict[str, int], deadlines: dict[str, float]) -> bool:
        """Take in events until each role's reply for its step is in or its deadline passes
        (a negative step: nothing owed yet).

        Returns True if a reply missed its deadline (the policy stands in for it).
        """
        owed = {role: k for role, k in steps.items() if k >= 0}
        self.collect_steps, self.reply_deadlines = owed, deadlines
        while True:
            now = time.monotonic()
            waiting = [
                r for r, k in owed.items() if k not in self.pending[r] and now < deadlines[r]
            ]
            if not waiting:
                break
            self._next_event(min(deadlines[r] for r in waiting))
        # Replies judged by when they arrived, not by when this thread got to them.
        self._drain()
        self.collect_steps, self.reply_deadlines = {}, {}
        for role, k in owed.items():
            if k not in self.pending[role] and k not in self.missed[role]:
                self._miss(role, k)
        return any(k not in self.pending[r] for r, k in owed.items())
