"""The lockstep scheduler of the hub: as fast as the endpoints go, pipelined.

Each input of step k+1 leaves as soon as the reply it depends on is in (the motor command
when the culture's spikes of step k arrive, the stimulation when the body's sensors of step
k arrive), so neither endpoint waits for the other's round trip; every endpoint still gets
exactly the inputs of the step-by-step scheme. Replies are taken, and the inputs that
depend on them sent, in the Zenoh thread they arrive on, under the loop's lock (a hand-over
to the loop's thread would put a wake-up on every step's critical path); the loop's thread
handles the other events, stands in by policy for replies owed longer than
``loop.reply_timeout_s``, publishes the status and runs the live analysis when nothing
else waits.

A mixin of :class:`hub.loop.Hub`: it works on the hub's state, under the rules written
there.
"""

from __future__ import annotations

import queue
import time
from collections.abc import Callable

from hub.protocol import ROLES, Message


class LockstepSteps:
    """The lockstep steps of :class:`~hub.loop.Hub`."""

    def _steps_lockstep(self) -> None:
        """As fast as the endpoints go, pipelined: each input of step k+1 leaves as soon as
        the reply it depends on is in (the motor command when the culture's spikes of step
        k arrive, the stimulation when the body's sensors of step k arrive), so neither
        endpoint waits for the other's round trip. Every endpoint still gets exactly the
        inputs of the Jacobi scheme, so results are those of a strict step-by-step loop.

        Replies are taken in the threads they arrive on (:meth:`_on_reply_direct`); this
        thread handles the other events, stands in by policy for replies that do not come
        within ``reply_timeout_s``, publishes the status and runs the live analysis."""
        n = self.cfg.n_steps
        timeout_s = self.cfg.loop.reply_timeout_s
        with self.lock:
            self.expect = {"body": 0, "culture": 0}
            self._last_progress = time.monotonic()
            self._send("body", self.inputs.motor_for(0, None))
            self._send("culture", self.inputs.stim_for(0, None))
            self.direct = True
        try:
            while True:
                with self.lock:
                    if self._failure is not None:
                        raise self._failure
                    if self._stop_reason or self.k_done >= n:
                        return
                    now = time.monotonic()
                    if self.state == "paused" or self.gone:  # gone: waiting for it to rejoin
                        self._last_progress = now
                    elif now - self._last_progress >= timeout_s:
                        self._stand_in(n)
                    until = self._last_progress + timeout_s
                # Analysis when nothing else waits, breaking off when something comes.
                idle = self.live is not None and not self._has_event()
                if idle and self._work_live(pause=self._has_event):
                    continue
                item = self._wait_event(until)
                with self.lock:
                    if item is not None:
                        self._handle(item)
                    self._advance(n)
                    self._tick()
        finally:
            with self.lock:
                self.direct = False
            if self.live is not None:
                self._work_live(flush=True)

    def _on_reply_direct(self, item: tuple) -> None:
        """A reply in lockstep, in the thread it came on: take it, send what it allows."""
        t0 = time.perf_counter()
        with self.lock:
            if not self.direct:  # the steps ended meanwhile: the loop's thread decides
                return self.inbox.put(item)
            try:
                self._handle(item)
                self._advance(self.cfg.n_steps)
            except BaseException as exc:  # the loop's thread raises it
                self.direct, self._failure = False, exc
                self.inbox.put(("wake",))
            self.times.direct_busy_s += time.perf_counter() - t0

    def _advance(self, n: int) -> None:
        """Lockstep: send every input whose reply is in (unless paused or stopping), and
        note the steps completed."""
        if self.state != "running" or self._stop_reason:
            return
        for role in ("culture", "body"):
            pending, expect = self.pending[role], self.expect
            while expect[role] in pending:
                self._pipeline(role, pending.pop(expect[role]), n)
        done = min(self.expect.values())
        if done > self.k_done:
            now = time.monotonic()
            self.times.step_wall_s[self.k_done : done] = (now - self._last_progress) / (
                done - self.k_done
            )
            self._last_progress = now
            self.k_done = self.k = done
            if done >= n:
                self.inbox.put(("wake",))

    def _stand_in(self, n: int) -> None:
        """Lockstep: no reply for ``reply_timeout_s``: the policy stands in for each reply
        owed (an input that waits on another reply is not owed yet)."""
        owed = [r for r in ROLES if self.last_sent.get(r, -1) >= self.expect[r] < n]
        for role in owed:
            self._miss(role, self.expect[role])
            self._pipeline(role, None, n)
        self._last_progress = time.monotonic()
        self._advance(n)

    def _pipeline(self, role: str, reply: Message | None, n: int) -> None:
        """Take the reply of ``role`` for its expected step k; send the other side step k+1."""
        k = self.expect[role]
        self.expect[role] = k + 1
        if k + 1 < n and not self._stop_reason:
            if role == "culture":
                self._send("body", self.inputs.motor_for(k + 1, reply))
            else:
                self._send("culture", self.inputs.stim_for(k + 1, reply))
        if role == "culture" and reply is not None and self.live is not None:
            self._live_in.put(reply)

    def _work_live(self, *, flush: bool = False, pause: Callable[[], bool] | None = None) -> bool:
        """Lockstep: feed the live burst detector the spikes handed over (``_live_in``) once
        ONLINE_EVERY_MS of them are in (``flush``: whatever is in, to the end), breaking off
        when ``pause()`` says so. Records each network burst completed. True if it worked."""
        live = self.live
        while True:
            try:
                live.add(self._live_in.get_nowait())
            except queue.Empty:
                break
        if not (flush or live.due):
            return False
        done = live.finish() if flush else live.work(pause=pause)
        with self.lock:
            self._record_network_bursts(done)
        return True

    def _has_event(self) -> bool:
        return not self.inbox.empty()
