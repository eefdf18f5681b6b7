"""The run's messages with its endpoints: each input sent, each reply taken.

An input goes out through the link (sealed), is noted in the ledger (a reply for its step
may come), timed for its reply's round trip, kept for an endpoint that may rejoin
(``policy.rejoin_s``), shown to live displays and recorded (``tx``). A reply is checked
(:class:`~hub.replies.ReplyChecker`), judged by its arrival time
(:class:`~hub.ledger.Ledger`), recorded with that verdict, shown to live displays and, the
culture's spikes, left for the burst observer. Both are on every step's critical path:
nothing here waits, and each does its work inline.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from hub.errors import HubError
from hub.protocol import ROLES, Message, MotorCommand, ProtocolError, StepWindow
from hub.view import ObserverView

if TYPE_CHECKING:
    from hub.config import ExperimentConfig
    from hub.ledger import Ledger
    from hub.link import HubLink
    from hub.online import OnlineAnalysis
    from hub.record import Recorder
    from hub.replies import ReplyChecker
    from hub.report import LoopTimes
    from hub.steps import Standing

log = logging.getLogger(__name__)


class Traffic:
    """Sends a run's inputs and takes its replies.

    Parameters
    ----------
    cfg : ExperimentConfig
        The run's experiment (its endpoints, ``[bus]`` keys, ``policy.rejoin_s``, ``loop``).
    run_id : str
    standing : Standing
        Where the run stands: a reply before the steps is dropped as early.
    ledger : Ledger
        What each role owes; judges each reply.
    checker : ReplyChecker
        What a reply must contain.
    times : LoopTimes
        Where each reply's round trip is written.

    Attributes
    ----------
    view : ObserverView
        What live displays are shown of the messages (:mod:`hub.telemetry` builds it).
    link : HubLink or None
        The hub's side of the bus, once the session is open.
    recorder : Recorder or None
        The run's record, while it is written.
    online : OnlineAnalysis or None
        The burst observer's run: the culture's spikes taken are left in its ``pending``.
    round_trip_ms : dict
        Role → the round trip of its latest reply (ms), for the status.
    """

    def __init__(
        self,
        cfg: ExperimentConfig,
        run_id: str,
        standing: Standing,
        ledger: Ledger,
        checker: ReplyChecker,
        times: LoopTimes,
    ):
        keys, ids = cfg.bus.keys, {role: cfg.endpoint(role).id for role in ROLES}
        self.input_key = {role: keys.input(role, i) for role, i in ids.items()}
        self.output_key = {role: keys.output(role, i) for role, i in ids.items()}
        self.cfg, self.run_id, self.standing = cfg, run_id, standing
        self.ledger, self.checker, self.times = ledger, checker, times
        self.view = ObserverView(run_id)
        self.link: HubLink | None = None
        self.recorder: Recorder | None = None
        self.online: OnlineAnalysis | None = None
        self.round_trip_ms: dict[str, float] = {}
        self.n_steps = n = cfg.n_steps
        # when each role's input of each step was put, for its reply's round trip (plain
        # lists: a numpy scalar read and NaN test cost microseconds a reply)
        self._put_at = {role: [math.nan] * n for role in ROLES}
        # the inputs each role has not answered yet, by step (sent again if it rejoins)
        self.unanswered: dict[str, dict[int, bytes]] = {role: {} for role in ROLES}
        self._keep_unanswered = cfg.policy.rejoin_s > 0

    def send(self, role: str, message: Message, raw: bytes | None = None) -> None:
        """Put an input to an endpoint and record it.

        Parameters
        ----------
        role : str
            ``"body"`` or ``"culture"``.
        message : Message
            The input.
        raw : bytes, optional
            ``message`` encoded already.
        """
        raw = raw or message.encode()
        # Stamped before the put: a reply can come (and be stamped) before the put returns.
        t_wall_ns = time.time_ns() if self.recorder else None
        put_at = time.monotonic()
        self.link.send(role, raw)
        self.ledger.sent(role, message.step)
        if 0 <= message.step < self.n_steps:
            self._put_at[role][message.step] = put_at
        if self._keep_unanswered:
            unanswered = self.unanswered[role]
            for step in [k for k in unanswered if k < self.ledger.expect[role]]:
                del unanswered[step]
            unanswered[message.step] = raw
        if self.view.observed:
            self.view.sent(message)
        if self.recorder:
            self.recorder.message("tx", self.input_key[role], raw, t_wall_ns)

    def resend_unanswered(self, role: str) -> None:
        """Put again the inputs ``role`` has not answered (in lockstep up to two are in
        flight), to an endpoint that rejoined; recorded once, when first sent."""
        for step in sorted(self.unanswered[role]):
            if step >= self.ledger.expect[role]:
                self._put_at[role][step] = time.monotonic()
                self.link.send(role, self.unanswered[role][step])

    def take(self, role: str, raw: bytes, t_wall_ns: int, t_arrival: float) -> None:
        """Check one reply, judge it by its arrival, record it with that verdict; show it
        and, the culture's, leave it for the burst observer.

        Parameters
        ----------
        role : str
            Whose reply.
        raw : bytes
            The reply, unsealed and reassembled.
        t_wall_ns : int
            When it came (wall clock, ns), as the record keeps it.
        t_arrival : float
            When it came (monotonic, s), what it is judged by (late, stale).
        """
        ledger = self.ledger
        running = self.standing.state != "waiting"
        try:
            message = self.checker.check(role, raw)
        except ProtocolError as exc:
            verdict, message = ledger.drop(role, exc.kind, str(exc)), None
        else:
            if role == "culture" and message.partial:
                verdict = ledger.judge_part(role, message, running=running)
                if verdict == "late":  # of a step stood in for: shown as a late reply is
                    self.view.took(message)
            else:
                verdict = ledger.judge(role, message, t_arrival, running=running)
                if verdict in ("rx", "late"):
                    step = message.step
                    if 0 <= step < self.n_steps:
                        put_at = self._put_at[role][step]
                        if put_at == put_at:  # not NaN: the input went out
                            rtt_s = t_arrival - put_at
                            self.times.round_trip_s[role][step] = rtt_s
                            self.round_trip_ms[role] = rtt_s * 1e3
                    if self.view.observed:
                        # live displays get a step's spikes whole (its parts merged): a
                        # display closes its rate bins up to the window's end when it gets them
                        self.view.took(ledger.pending[role].get(step, message))
        if self.recorder:
            self.recorder.message(verdict, self.output_key[role], raw, t_wall_ns)
        if role == "culture" and self.online is not None and verdict in ("rx", "late"):
            if verdict == "late" and message.partial:
                return  # a part of a step stood in for: the observer counts that step missing
            # the observer takes a step's spikes at once: with the parts streamed before;
            # a late step's too, as the record keeps them
            taken = ledger.pending[role].get(message.step, message)
            self.online.pending.append(raw if taken is message else taken.encode())

    def stop_body(self, next_event: Callable[[float], None]) -> None:
        """Put the body a stop, the run's last word to it whatever ended the run, and once
        the steps began handle events (``next_event(until)``) for at most
        ``loop.final_stop_wait_s`` until its reply to it comes: the proof that it was
        applied. Recorded either way (a ``final_stop`` event)."""
        ledger, wait_s = self.ledger, self.cfg.loop.final_stop_wait_s
        step = ledger.final_step = ledger.last_sent.get("body", -1) + 1
        window = StepWindow.of(self.run_id, step, self.cfg.loop.period_ms / 1e3)
        self.send("body", MotorCommand.stop(window))
        if self.standing.state == "waiting":  # the run was never announced: nothing answers
            return
        t0 = time.monotonic()
        until = t0 + wait_s
        try:
            while step not in ledger.pending["body"] and time.monotonic() < until:
                next_event(until)
        except HubError:  # the body died meanwhile: it stops itself (input timeout, lease)
            pass
        seen = step in ledger.pending["body"]
        if self.recorder:
            waited_s = round(time.monotonic() - t0, 4)
            self.recorder.event("final_stop", step=step, acknowledged=seen, wait_s=waited_s)
        if not seen:
            log.warning(
                "the body did not answer the final stop within %.2f s (loop.final_stop_wait_s);"
                " it stops itself on its own input timeout",
                wait_s,
            )

    def refused(self, role: str, raw: bytes, kind: str, detail: str, t_wall_ns: int) -> None:
        """A payload on an endpoint's reply key that did not unseal or reassemble: not the
        endpoint's; counted as dropped and recorded capped.

        Parameters
        ----------
        role : str
            Whose reply key it came on.
        raw : bytes
            The payload.
        kind, detail : str
            The drop's kind (``foreign``, ``frame``) and what was wrong.
        t_wall_ns : int
            When it came (wall clock, ns).
        """
        self.ledger.drop(role, kind, detail)
        if self.recorder and raw:
            self.recorder.message("drop", self.output_key[role], raw, t_wall_ns)
