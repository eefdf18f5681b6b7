"""What a running hub answers: control requests (``neuvision ctl``) and status questions.

A control request on ``hub/control`` pauses the steps (each endpoint told, so that it makes
itself safe at once), resumes them, stops the run after the step under way, or asks for
the run's config or status; every request is recorded. A question on ``hub/status`` gets
the status (read-only: observers that may not send control commands ask there).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING

from hub.bus import payload_bytes
from hub.protocol import ControlReply, ControlRequest, HubStatus, ProtocolError
from hub.steps import STOPPED_BY_CONTROL

if TYPE_CHECKING:
    from hub.ledger import Ledger
    from hub.report import LoopTimes
    from hub.steps import Standing

log = logging.getLogger(__name__)


class Control:
    """Answers the queries on ``hub/control`` and ``hub/status``.

    Parameters
    ----------
    standing : Standing
        Where the run stands: paused, resumed, stopping here.
    times : LoopTimes
        Where the time paused is kept.
    ledger : Ledger
        A malformed request is counted there as dropped (role ``control``).
    status : callable
        The run's :class:`~hub.protocol.HubStatus` now.
    config : callable
        The run's config as recorded (a plain dict).
    hold : callable
        ``hold(True)``: tell each endpoint the run is paused, ``hold(False)`` resumed; each
        one's acknowledgement by role.
    record_event : callable
        ``record_event(name, **details)``: an event in the run's record.
    """

    def __init__(
        self,
        standing: Standing,
        times: LoopTimes,
        ledger: Ledger,
        status: Callable[[], HubStatus],
        config: Callable[[], dict],
        hold: Callable[[bool], dict[str, bool]],
        record_event: Callable[..., None],
    ):
        self.standing, self.times, self.ledger = standing, times, ledger
        self._status, self._config, self._hold = status, config, hold
        self._record_event = record_event

    def answer(self, query) -> None:
        """Carry out the control request of ``query`` and reply whether it was done."""
        standing = self.standing
        try:
            request = ControlRequest.decode(payload_bytes(query))
        except ProtocolError as exc:
            self.ledger.drop("control", exc.kind, str(exc))
            return _reply(query, ControlReply(ok=False, state=standing.state, reason=str(exc)))
        self._record_event("control", cmd=request.cmd)
        ok, reason, data = True, "", None
        if request.cmd == "pause":
            ok = standing.state == "running"
            if ok:
                standing.state = "paused"
                self.times.pause()
                self._tell_hold(True)
        elif request.cmd == "resume":
            ok = standing.state == "paused"
            if ok:
                self._tell_hold(False)
                self.times.resume()
                standing.state = "running"
        elif request.cmd == "stop":
            standing.stop_reason = standing.stop_reason or STOPPED_BY_CONTROL
        elif request.cmd == "config":
            data = self._config()
        data = data if data is not None else self._status().to_dict()
        if not ok:
            reason = f"cannot {request.cmd} while {standing.state}"
        # The state the command leads to, as pause and resume reply: a stop takes effect
        # after the current step.
        state = "stopping" if request.cmd == "stop" else standing.state
        _reply(query, ControlReply(ok=ok, state=state, reason=reason, data=data))

    def answer_status(self, query) -> None:
        """Reply to a question on ``hub/status`` with the status now."""
        _reply(query, self._status())

    def _tell_hold(self, hold: bool) -> None:
        """Tell each endpoint the run is paused (it makes itself safe at once: the wheels
        stop, nothing is delivered) or resumed; record who acknowledged."""
        taken = self._hold(hold)
        self._record_event("hold" if hold else "unhold", **taken)
        if not all(taken.values()):
            log.warning("not every endpoint acknowledged the %s: %s",
                        "pause" if hold else "resume", taken)  # fmt: skip


def _reply(query, reply: ControlReply | HubStatus) -> None:
    """Answer ``query`` with ``reply`` and let it go."""
    query.reply(query.key_expr, reply.encode())
    query.drop()
