"""What the hub is owed and what it got: each role's replies by step, judged on arrival.

Plain data, no bus and no clock of its own: the loop tells the ledger what it sent
(:meth:`Ledger.sent`), which step each role owes (``expect``) and, in realtime, by when
(:meth:`Ledger.await_replies`); each reply that passed :class:`~hub.replies.ReplyChecker`
is judged with the time it *arrived* (:meth:`Ledger.judge`), so a reply in before its
deadline is on time however late the loop's thread looked at it, and one in after it is
late however soon. A culture may stream a step's spikes in parts before its reply
(:meth:`Ledger.judge_part`): the reply accepted is then all of them. The verdicts are the
record's (``rx``, ``late``, ``part``, ``final``, ``drop``);
the counts are the run's (``late``, ``missing``, ``dropped``).
"""

from __future__ import annotations

import logging
import time
from collections import Counter, defaultdict
from collections.abc import Callable

from hub.protocol import ROLES, Message, merge_parts

log = logging.getLogger(__name__)


class Ledger:
    """Each role's replies by step: accepted, missing (stood in for), late, dropped.

    Parameters
    ----------
    on_event : callable
        Called as ``on_event(name, **details)`` for what the record keeps as an event:
        ``missed``, ``late``, and the first ``dropped`` of each kind and role.

    Attributes
    ----------
    expect : dict
        Role → the step whose reply it owes next.
    pending : dict
        Role → {step: reply} accepted and not yet used by the loop (with its parts merged).
    parts : dict
        Role → {step: [part, ...]} streamed before their step's reply.
    stranded : list
        Parts of steps that went missing: no reply will take them (for live displays).
    missed : dict
        Role → steps whose reply missed its deadline (the policy stood in for it).
    late : Counter
        Role → replies that came after the policy stood in for them.
    dropped : dict
        Role → Counter of dropped messages by kind.
    final_step : int
        The step of the body's final stop once sent (its answer is kept apart), else -1.
    silent_since : dict
        Role → when (monotonic) the first of its replies stood in for one after another
        was missed; a role is gone from it once it answers (``policy.silent_s``).
    """

    def __init__(self, on_event: Callable[..., None] = lambda name, **details: None):
        self.on_event = on_event
        self.expect = dict.fromkeys(ROLES, 0)
        self.last_sent: dict[str, int] = {}
        self.pending: dict[str, dict[int, Message]] = {role: {} for role in ROLES}
        self.parts: dict[str, dict[int, list[Message]]] = {role: {} for role in ROLES}
        self.stranded: list[Message] = []
        self.missed: dict[str, set[int]] = defaultdict(set)
        self.late: Counter[str] = Counter()
        self.dropped: dict[str, Counter[str]] = defaultdict(Counter)
        self.final_step = -1
        self.silent_since: dict[str, float] = {}
        # realtime: the step each role's reply is awaited for now, and by when (monotonic)
        self._owed: dict[str, int] = {}
        self._deadlines: dict[str, float] = {}
        self._in_late: dict[str, int] = {}  # owed replies that came after their deadline

    def sent(self, role: str, step: int) -> None:
        """An input went to a role: a reply for it may come.

        Parameters
        ----------
        role : str
            ``"body"`` or ``"culture"``.
        step : int
            The input's step.
        """
        self.last_sent[role] = step

    def judge(self, role: str, message: Message, t_arrival: float, *, running: bool) -> str:
        """The verdict on one checked reply.

        Parameters
        ----------
        role : str
            Whose reply it is.
        message : Message
            The reply, checked by :class:`~hub.replies.ReplyChecker`.
        t_arrival : float
            When it arrived (monotonic, s): a reply owed now that came after its
            deadline is missed and late, however soon the loop looked at it.
        running : bool
            Whether the run's steps have started (False: any reply is early).

        Returns
        -------
        str
            ``rx``: accepted, now in ``pending``; ``late``: in after the policy stood in
            for it (counted); ``final``: the answer to the final stop; ``drop``: early, a
            duplicate, stale or from the future (counted by kind).
        """
        step, expected = message.step, self.expect[role]
        if role == "body" and step == self.final_step:
            self.pending[role][step] = message
            return "final"
        if not running:
            return self.drop(role, "early", f"reply for step {step} before the run started")
        missed = self.missed[role]
        owed_now = step == self._owed.get(role)
        if owed_now and t_arrival > self._deadlines[role] and step not in missed:
            self.miss(role, step)  # in after its deadline, however soon the loop looked
            self._in_late[role] = step  # ... and late (below), not missing when it settles
        if expected <= step <= self.last_sent.get(role, -1) and step not in missed:
            if step in self.pending[role]:
                return self.drop(role, "duplicate", f"second reply for step {step}")
            parts = self.parts[role]
            if parts:  # streamed before this reply (contract v4)
                message = merge_parts(parts.pop(step, []), message)
            self.pending[role][step] = message
            if self.silent_since:
                self.silent_since.pop(role, None)
            return "rx"
        if step in missed:
            self.silent_since.pop(role, None)
            self.late[role] += 1
            missed.discard(step)
            self.on_event("late", role=role, step=step, at_step=expected)
            return "late"
        if step <= expected:
            return self.drop(role, "stale", f"reply for step {step} awaiting step {expected}")
        return self.drop(role, "future", f"reply for step {step} awaiting step {expected}")

    def judge_part(self, role: str, message: Message, *, running: bool) -> str:
        """The verdict on one part of a step's reply (contract v4's partial SpikeBatch).

        Parameters
        ----------
        role : str
            Whose part it is.
        message : Message
            The part, checked by :class:`~hub.replies.ReplyChecker`.
        running : bool
            Whether the run's steps have started (False: any part is early).

        Returns
        -------
        str
            ``part``: kept for its step's reply; ``late``: of a step the policy stood in
            for already (the run's data, not a late reply); ``drop``: early, stale, from
            the future, or after its step's reply (counted by kind).
        """
        step, expected = message.step, self.expect[role]
        if not running:
            return self.drop(role, "early", f"a part of step {step} before the run started")
        if step in self.missed[role]:
            return "late"
        if expected <= step <= self.last_sent.get(role, -1):
            if step in self.pending[role]:
                return self.drop(role, "duplicate", f"a part of step {step} after its reply")
            self.parts[role].setdefault(step, []).append(message)
            return "part"
        if step <= expected:
            return self.drop(role, "stale", f"a part of step {step} awaiting step {expected}")
        return self.drop(role, "future", f"a part of step {step} awaiting step {expected}")

    def owed(self, n_steps: int) -> list[str]:
        """The roles that owe a reply now: the input of the step they owe went out (an
        input that waits on another reply is not owed yet), and the run has that step."""
        expect, last_sent = self.expect, self.last_sent
        return [r for r in ROLES if last_sent.get(r, -1) >= expect[r] < n_steps]

    def miss(self, role: str, step: int) -> None:
        """A reply is missing: the policy stands in for it (its parts, recorded already,
        are stranded: no reply will take them).

        Parameters
        ----------
        role : str
            Whose reply is missing.
        step : int
            The step it was owed for.
        """
        self.stranded.extend(self.parts[role].pop(step, ()))
        self.missed[role].add(step)
        self.silent_since.setdefault(role, time.monotonic())
        self.on_event("missed", role=role, step=step)

    def silent(self, now: float, silent_s: float) -> list[str]:
        """The roles whose replies were all stood in for, one after another, for longer
        than ``silent_s`` up to ``now``.

        Parameters
        ----------
        now : float
            The time to judge at (monotonic, s).
        silent_s : float
            How long a role's replies may all be stood in for (``policy.silent_s``).
        """
        return [role for role, since in self.silent_since.items() if now - since > silent_s]

    def drop(self, role: str, kind: str, detail: str) -> str:
        """Count (and log once per kind and role) a dropped message.

        Parameters
        ----------
        role : str
            Whose message it was.
        kind : str
            Why it was dropped (``early``, ``duplicate``, ``stale``, ``future``, ...).
        detail : str
            What the log line and the ``dropped`` event say about it.

        Returns
        -------
        str
            ``"drop"``, the record's verdict.
        """
        if not self.dropped[role][kind]:
            log.warning("dropped a %s message (%s): %s", role, kind, detail)
            self.on_event("dropped", role=role, kind=kind, detail=detail)
        self.dropped[role][kind] += 1
        return "drop"

    # ------------------------------------------------------------ realtime deadlines

    def await_replies(self, steps: dict[str, int], deadlines: dict[str, float]) -> None:
        """Each role in ``steps`` owes the reply of that step by its deadline.

        Parameters
        ----------
        steps : dict
            Role → the step whose reply it owes now; a negative step owes nothing yet.
        deadlines : dict
            Role → when that reply is due (monotonic, s).
        """
        self._owed = {role: k for role, k in steps.items() if k >= 0}
        self._deadlines = dict(deadlines)
        self._in_late = {}

    def waiting(self, now: float) -> list[str]:
        """The roles whose reply is not in and whose deadline has not passed at ``now``."""
        return [
            r
            for r, k in self._owed.items()
            if k not in self.pending[r] and now < self._deadlines[r]
        ]

    def next_deadline(self, roles: list[str]) -> float:
        """The earliest deadline (monotonic, s) of ``roles``' owed replies (not empty)."""
        return min(self._deadlines[r] for r in roles)

    def settle(self) -> bool:
        """The deadlines are over: each reply not in is missing. True if any was missing."""
        owed, self._owed, self._deadlines = self._owed, {}, {}
        in_late, self._in_late = self._in_late, {}
        for role, k in owed.items():
            if (
                k not in self.pending[role]
                and k not in self.missed[role]
                and in_late.get(role) != k
            ):
                self.miss(role, k)
        return any(k not in self.pending[r] for r, k in owed.items())
