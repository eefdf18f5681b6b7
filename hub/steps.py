"""What the hub and its schedulers of the steps share, and see of each other.

A scheduler (:class:`~hub.lockstep.Lockstep`, :class:`~hub.realtime.Realtime`) decides
when each step's inputs go and how long their replies are waited for; the hub
(:class:`~hub.loop.Hub`) does everything else. They meet here:

- :class:`Standing`: where the run stands (paused, stopping, who is on the bus, an
  endpoint awaited back), written by the hub's event handlers, read by the scheduler;
- :class:`LoopPort`: the hub's services that a scheduler calls (send an input, take the
  events, the loop's chores);
- :class:`Scheduler`: what the hub asks of a scheduler, the base of both.

A scheduler also writes the run's :class:`~hub.ledger.Ledger` (which step each role owes,
the replies in) and :class:`~hub.report.LoopTimes` (each step's timing): plain data, given
to it when it is made.
"""

from __future__ import annotations

import gc
import logging
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

from hub.errors import HubError
from hub.scheduling import CpusAwake, hold_cpus_awake

if TYPE_CHECKING:
    from hub.config import LoopSection
    from hub.ledger import Ledger
    from hub.policy import InputPolicy
    from hub.protocol import Description, Message
    from hub.report import LoopTimes
    from hub.scheduling import Scheduling

log = logging.getLogger(__name__)

# The longest a thread holds the interpreter while another wants it during the steps.
# Python's default, 5 ms, would let the recorder or a status hold up a step start
# (realtime) or keep Zenoh's callback from handing the loop a reply (both modes).
GIL_SWITCH_S = 2e-4
# Why a run ended before its last step, when the user asked: a signal, or ``ctl stop``.
INTERRUPTED, STOPPED_BY_CONTROL = "interrupted", "stopped by control"


class StoppedBeforeSteps(Exception):
    """A stop asked for by the user (a signal, ``ctl stop``) before the first step: the run
    ends as ``interrupted`` or ``stopped``, as the same stop during the steps does."""


@dataclass(eq=False)
class Standing:
    """Where a run stands, shared by the hub's parts and its scheduler.

    Attributes
    ----------
    state : str
        ``waiting`` (before the steps), ``running``, ``paused`` (``ctl pause``: no step
        starts and no input goes) or ``stopped`` (after the steps).
    stop_reason : str or None
        Why the run must end before its last step, once asked (a signal, ``ctl stop``) or
        decided: the steps end after the one under way.
    ended : tuple of str or None
        ``(outcome, reason)`` once the run is over (said in the final status).
    alive : set of (str, str)
        The ``(role, id)`` of each participant whose liveliness token is on the bus.
    awaited : dict
        Role → ``(since, step)``: when (monotonic) and at which step an endpoint vanished
        that may come back within ``policy.rejoin_s``; a lockstep run waits for it.
    """

    state: str = "waiting"
    stop_reason: str | None = None
    ended: tuple[str, str] | None = None
    alive: set[tuple[str, str]] = field(default_factory=set)
    awaited: dict[str, tuple[float, int]] = field(default_factory=dict)

    def stopped_outcome(self) -> str:
        """The outcome of a run stopped before its end: ``interrupted`` or ``stopped``."""
        return "interrupted" if self.stop_reason == INTERRUPTED else "stopped"

    def check_stop(self, awaiting: str) -> None:
        """Raise if a stop came while the hub waits for ``awaiting`` before the steps.

        Raises
        ------
        StoppedBeforeSteps
            The user's stop (a signal, ``ctl stop``): the run ends as it would in the steps.
        HubError
            Any other (a local endpoint exited): a fault.
        """
        if self.stop_reason in (INTERRUPTED, STOPPED_BY_CONTROL):
            raise StoppedBeforeSteps(self.stop_reason)
        if self.stop_reason:
            raise HubError(f"stopped while waiting for {awaiting} ({self.stop_reason})")


@contextmanager
def ready_for_steps(keep_cpus_awake: bool) -> Iterator[CpusAwake]:
    """The hub's process made ready for the steps, and as it was after them: what was
    allocated so far kept out of the cyclic collector (long-lived; the collector's full
    passes would stall realtime steps), the interpreter handed between threads every
    ``GIL_SWITCH_S``, idle CPUs kept awake (``loop.keep_cpus_awake``).

    Yields
    ------
    CpusAwake
        Whether idle CPUs are kept awake, or why not.
    """
    gc.collect()
    gc.freeze()
    switch_s = sys.getswitchinterval()
    sys.setswitchinterval(GIL_SWITCH_S)
    awake = hold_cpus_awake(keep_cpus_awake)
    if not awake.held and keep_cpus_awake:
        log.info("idle CPUs may sleep during the steps: %s", awake.reason)
    try:
        yield awake
    finally:
        awake.release()
        sys.setswitchinterval(switch_s)


class LoopPort(Protocol):
    """The hub's services to a scheduler of the steps (:class:`~hub.loop.Hub` gives them).

    A scheduler binds the ones it calls on every step once (a bound method kept), so that
    none is looked up through two objects per step.

    Attributes
    ----------
    view_due_at : float
        When (monotonic) the next view for live displays falls due.
    """

    view_due_at: float

    def send(self, role: str, message: Message, raw: bytes | None = None) -> None:
        """Put an input to an endpoint, and record it.

        Parameters
        ----------
        role : str
            ``"body"`` or ``"culture"``.
        message : Message
            The input.
        raw : bytes, optional
            ``message`` encoded already.
        """

    def resend_unanswered(self, role: str) -> None:
        """Put again the inputs ``role`` has not answered (it came back)."""

    def handle(self, item: tuple) -> None:
        """Act on one event (:mod:`hub.link`'s tuples: a reply is checked, judged by the
        ledger and recorded; a control request answered; ...)."""

    def wait_event(self, until: float) -> tuple | None:
        """The next event for the loop's thread, waiting at most until ``until``
        (monotonic) or a chore of the loop falls due; None if none came."""

    def drain(self) -> None:
        """Handle every event waiting for the loop's thread."""

    def post(self, item: tuple) -> None:
        """Hand an event to the loop's thread (``("wake",)``: look at the state again)."""

    def tick(self) -> None:
        """The loop's chores that are due: the status, the record's flush, the deadline of
        an endpoint awaited back."""

    def share(self, now: float, *, view: bool = True) -> None:
        """After a step: the culture's spikes left for the burst observer and, with
        ``view``, a view for live displays, each if due.

        Parameters
        ----------
        now : float
            The time (monotonic, s) they are due by.
        view : bool
            Whether a view may be built now (realtime: not when the next step is near).
        """

    def record_event(self, name: str, **details) -> None:
        """Record something the scheduler noticed (an ``ev`` frame)."""


class Scheduler:
    """A scheduler of the steps, as the hub sees it: the base of
    :class:`~hub.lockstep.Lockstep` and :class:`~hub.realtime.Realtime`, which keep the
    steps' own state and time them.

    Parameters
    ----------
    port : LoopPort
        The hub's services (send an input, take the events, the loop's chores).
    standing : Standing
        Where the run stands: paused, stopping, an endpoint awaited back.
    ledger : Ledger
        Which step each role owes (``expect``, moved on by the scheduler) and what came.
    times : LoopTimes
        Where the steps' timing is written (each step's wall time; in realtime its
        lateness and the late steps).
    loop : LoopSection
        The ``[loop]`` settings.
    n_steps : int
        The run's steps.

    Attributes
    ----------
    k, k_done : int
        The step under way, and the steps whose every reply is in (or stood in for).
    scheduling : Scheduling or None
        How the hub's threads were scheduled for the steps (realtime), for the manifest.
    """

    scheduling: Scheduling | None = None

    def __init__(
        self,
        port: LoopPort,
        standing: Standing,
        ledger: Ledger,
        times: LoopTimes,
        loop: LoopSection,
        n_steps: int,
    ):
        self.k = self.k_done = 0
        self._port, self._standing, self._ledger, self._times = port, standing, ledger, times
        self._loop, self._n = loop, n_steps

    def deliver(self, item: tuple) -> None:
        """An event from the bus, on the thread it came on (the link's callback)."""
        raise NotImplementedError

    def run(self, inputs: InputPolicy, descriptions: dict[str, Description]) -> None:
        """Step to the end of the run, or until a stop; the steps' timing starts and ends
        here.

        Parameters
        ----------
        inputs : InputPolicy
            Gives each step's inputs (coded from the replies, or stood in for).
        descriptions : dict of str to Description
            The endpoints' descriptions, by role.
        """
        raise NotImplementedError

    def rejoined(self, role: str) -> None:
        """``role`` is back on the bus and has the run again."""
