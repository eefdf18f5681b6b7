"""The run's endpoints as the hub meets them: each describes itself, takes the run, is told
when the run pauses and resumes, and is told its end (ARCHITECTURE.md, "Start-up"; the wire
contract's ``describe`` and ``run`` queryables).

:class:`Roster` asks and checks; what the hub keeps of the answers (the descriptions, each
endpoint's host and clock offset) it returns as plain data. A description that does not
suit the run's loop (:func:`check_fits_loop`), a second endpoint answering under the same
name, or one serving other settings than the hub's experiment is a :class:`HubError`
before the first step.
"""

from __future__ import annotations

import time

import zenoh

from hub.config import ExperimentConfig, LoopSection
from hub.errors import HubError
from hub.launch import settings_digest, settings_digests
from hub.link import HubLink
from hub.protocol import Description, ProtocolError, RunEnd, RunHold, RunReply, RunStart
from hub.record import Recorder

DESCRIBE_TIMEOUT_S = 5.0
ANNOUNCE_TIMEOUT_S = 5.0
HOLD_TIMEOUT_S = 1.0
END_TIMEOUT_S = 1.0
FINAL_COUNTERS_TIMEOUT_S = 2.0


class Roster:
    """Asks the run's endpoints (``cfg``'s ``body`` and ``culture``) over ``link``.

    Parameters
    ----------
    cfg : ExperimentConfig
    link : HubLink
        The hub's declarations on the bus (its queries go through it).
    recorder : Recorder or None
        Where each description is recorded as it came (``rx`` on the ``describe`` key).
    """

    def __init__(self, cfg: ExperimentConfig, link: HubLink, recorder: Recorder | None = None):
        self.cfg = cfg
        self.link = link
        self.keys = link.keys
        self.recorder = recorder
        self._digests: dict[str, str | None] = {}

    def describe(self, role: str, i: str) -> tuple[Description, dict]:
        """Ask an endpoint to describe itself.

        Parameters
        ----------
        role : str
            ``"body"`` or ``"culture"``.
        i : str
            The endpoint's id.

        Returns
        -------
        desc : Description
            Its description.
        where : dict
            What the manifest keeps of where it runs: ``host``, ``clock_offset_ms`` (its
            clock minus the hub's at the middle of the query, ± half
            ``describe_round_trip_ms``; None if it sent no time), ``describe_round_trip_ms``,
            ``settings_digest``.

        Raises
        ------
        HubError
            No description, an invalid one, several endpoints answering as ``role/i``, or
            one serving other settings than this hub's experiment.
        """
        key = self.keys.describe(role, i)
        desc = None
        t0 = time.time()
        replies = self.link.query(key, timeout_s=DESCRIBE_TIMEOUT_S)
        t1 = time.time()
        described = []
        for raw in replies:
            if self.recorder:
                self.recorder.message("rx", key, raw)
            try:
                desc = Description.decode(raw)
            except ProtocolError as exc:
                raise HubError(f"{role}/{i} sent an invalid description: {exc}") from None
            described.append(desc)
        if len(described) > 1:
            raise self.several(role, i, [d.counters for d in described])
        if desc is None or desc.role != role or desc.id != i:
            raise HubError(f"{role}/{i} did not describe itself on {key}")
        counters = desc.counters or {}
        theirs, ours = counters.get("settings_digest"), self._settings_digest(role)
        if isinstance(theirs, str) and ours is not None and theirs != ours:
            which = differing_settings(counters.get("settings_digests"), self.cfg, role)
            raise HubError(
                f"{role}/{i} serves other settings than this hub's experiment ({which}): "
                f"start it with the hub's experiment file and the same --set items"
            )
        their_time = counters.get("unix_time_s")
        where = {
            "host": counters.get("host", {}),
            "clock_offset_ms": (their_time - (t0 + t1) / 2) * 1e3
            if isinstance(their_time, float)
            else None,
            "describe_round_trip_ms": (t1 - t0) * 1e3,
            "settings_digest": theirs if isinstance(theirs, str) else None,
        }
        return desc, where

    def announce(self, role: str, i: str, start: RunStart) -> None:
        """Give an endpoint the run (again, when it rejoins: the same id, timing and key).

        Parameters
        ----------
        role : str
            ``"body"`` or ``"culture"``.
        i : str
            The endpoint's id.
        start : RunStart
            The run's announcement (its key is that endpoint's).

        Raises
        ------
        HubError
            It did not answer, refused, or more than one endpoint answered.
        """
        answers = run_replies(self.link, self.keys.run(role, i), start, ANNOUNCE_TIMEOUT_S)
        if not answers:
            raise HubError(f"{role}/{i} did not answer the run's announcement")
        if len(answers) > 1:  # another one came up since the description: ask who
            found = self._counters_of(role, i)
            raise self.several(role, i, found + [None] * (len(answers) - len(found)))
        refusals = [a.reason for a in answers if not a.ok or a.run != start.run]
        if refusals:
            raise HubError(f"{role}/{i} refused the run: {refusals[0]}")

    def hold(self, who: list[tuple[str, str]], run: str, hold: bool) -> dict[str, bool]:
        """Tell endpoints that the run is paused (each makes itself safe at once: the
        wheels stop, nothing is delivered) or resumed.

        Parameters
        ----------
        who : list of (str, str)
            The endpoints, as (role, id).
        run : str
            The run id.
        hold : bool
            True: paused; False: resumed.

        Returns
        -------
        dict
            Role → whether that endpoint acknowledged (within :data:`HOLD_TIMEOUT_S`).
        """
        message = RunHold(run=run, hold=hold)
        return {
            role: any(
                a.ok
                for a in run_replies(self.link, self.keys.run(role, i), message, HOLD_TIMEOUT_S)
            )
            for role, i in who
        }

    def end(self, who: list[tuple[str, str]], run: str, outcome: str) -> None:
        """Tell endpoints that the run is over (each makes itself safe); answers are not
        waited for beyond :data:`END_TIMEOUT_S` each, nor checked.

        Parameters
        ----------
        who : list of (str, str)
            The endpoints, as (role, id).
        run : str
            The run id.
        outcome : str
            The run's outcome, as the manifest says it.
        """
        end = RunEnd(run=run, outcome=outcome).encode()
        for role, i in who:
            self.link.query(self.keys.run(role, i), end, timeout_s=END_TIMEOUT_S)

    def final_counters(self, who: list[tuple[str, str]]) -> dict[str, dict]:
        """Each of ``who``'s own counters at the end (drops, steps, busy time), by role, from
        those that answer."""
        out = {}
        for role, i in who:
            for raw in self.link.query(
                self.keys.describe(role, i), timeout_s=FINAL_COUNTERS_TIMEOUT_S
            ):
                try:
                    out[role] = Description.decode(raw).counters or {}
                except ProtocolError:
                    pass
        return out

    def _counters_of(self, role: str, i: str) -> list:
        """The counters (host and process id among them) of every endpoint describing
        itself as ``role/i`` now; those that do not decode are left out."""
        out = []
        for raw in self.link.query(self.keys.describe(role, i), timeout_s=DESCRIBE_TIMEOUT_S):
            try:
                out.append(Description.decode(raw).counters)
            except ProtocolError:
                continue
        return out

    def several(self, role: str, i: str, counters: list) -> HubError:
        """The error for more than one endpoint answering as ``role/i`` (one left running
        elsewhere): each would take the run and step, and the hub take whichever reply
        came first.

        Parameters
        ----------
        role, i : str
            The role and id they answer as.
        counters : list
            Each one's description counters (None where unknown): their hosts and process
            ids are named.
        """
        where = []
        for c in counters:
            host = (c or {}).get("host") or {}
            if host.get("pid") is not None:
                where.append(f"{host.get('hostname', '?')} pid {host['pid']}")
        named = f" ({', '.join(where)})" if where else ""
        return HubError(
            f"{len(counters)} endpoints answer as {role}/{i} on session "
            f"{self.cfg.bus.session!r}{named}: stop all but one"
        )

    def elsewhere(self, missing: set[tuple[str, str]]) -> str:
        """Where on this hub's bus the ``missing`` participants are: under other sessions
        (an endpoint started with another ``--session`` reaches the router, not the run), or
        under another id on this one: "; body/0 is on this hub's bus under session 'lab3'
        (start it with --session default)" or "; ... a body/1 is (body.id ...)", or ""."""
        found = []
        session = self.cfg.bus.session
        for role, i in sorted(missing):
            sessions, ids = set(), set()
            try:
                replies = self.link.session.liveliness().get(f"nv/*/alive/{role}/*", timeout=0.5)
                for reply in replies:
                    if reply.ok is not None:
                        parts = str(reply.ok.key_expr).split("/")  # nv/<session>/alive/role/id
                        if len(parts) != 5:
                            continue
                        if parts[1] != session and parts[4] == i:
                            sessions.add(parts[1])
                        elif parts[1] == session and parts[4] != i:
                            ids.add(parts[4])
            except zenoh.ZError:
                continue
            if sessions:
                names = " and ".join(repr(n) for n in sorted(sessions))
                found.append(
                    f"{role}/{i} is on this hub's bus under session {names} (start it with "
                    f"--session {session})"
                )
            if ids:
                others = " and ".join(f"{role}/{n}" for n in sorted(ids))
                found.append(
                    f"on session {session!r} {others} is, not {role}/{i} ({role}.id in the "
                    "hub's and the endpoint's experiment files must agree)"
                )
        return f"; {', '.join(found)}" if found else ""

    def _settings_digest(self, role: str) -> str | None:
        """The digest of this hub's ``role`` settings (:func:`hub.launch.settings_digest`),
        worked out once; None when its kind does not load here."""
        if role not in self._digests:
            self._digests[role] = settings_digest(self.cfg, role)
        return self._digests[role]


#: the most settings a refusal names
MAX_NAMED_SETTINGS = 5


def differing_settings(theirs, cfg: ExperimentConfig, role: str) -> str:
    """Which of ``role``'s settings an endpoint serves otherwise than this hub, from its
    per-setting digests (:func:`hub.launch.settings_digests`), said for a refusal.

    Parameters
    ----------
    theirs : dict or None
        The endpoint's digests by dotted key (None: an endpoint that sends none).
    cfg : ExperimentConfig
        This hub's experiment.
    role : str
        ``"body"`` or ``"culture"``.
    """
    ours = settings_digests(cfg, role)
    if not isinstance(theirs, dict) or ours is None:
        return f"{role}.kind and {role}.params as resolved, the seed included, differ"
    keys = sorted(set(ours) | set(theirs))
    differ = [k for k in keys if ours.get(k) != theirs.get(k)]
    named = ", ".join(differ[:MAX_NAMED_SETTINGS])
    more = (
        f" and {len(differ) - MAX_NAMED_SETTINGS} more" if len(differ) > MAX_NAMED_SETTINGS else ""
    )
    return f"{'it differs in' if differ else 'they differ'} {named}{more}".rstrip()


def run_replies(link: HubLink, key: str, request, timeout_s: float) -> list[RunReply]:
    """The ``RunReply``s to a request on a ``run`` queryable (a malformed one left out).

    Parameters
    ----------
    link : HubLink
        Through which the query goes.
    key : str
        The ``run`` queryable's key.
    request : Message
        What is asked (``RunStart``, ``RunHold``, ``ObserverStart``, ...), encoded here.
    timeout_s : float
        How long to wait for replies.
    """
    answers = []
    for raw in link.query(key, request.encode(), timeout_s=timeout_s):
        try:
            answers.append(RunReply.decode(raw))
        except ProtocolError:
            continue
    return answers


def check_fits_loop(desc: Description, loop: LoopSection) -> str | None:
    """Whether an endpoint so described can take a run of ``loop``: a warning to record, or
    None.

    Parameters
    ----------
    desc : Description
        The endpoint's description.
    loop : LoopSection
        The run's loop settings.

    Raises
    ------
    HubError
        A real device (``realtime_only``) in a lockstep run; or one that answers each window
        after it has passed, in realtime with a deadline not between one and two periods.
    """
    who = f"{desc.role}/{desc.id} ({desc.kind})"
    period_ms = loop.period_ms
    if desc.realtime_only and loop.mode != "realtime":
        raise HubError(
            f"{who} is a real device: it runs in real time only and cannot take a "
            f'lockstep run; set loop.mode = "realtime"'
        )
    if desc.answers_after_window and (problem := loop.late_window_problem()):
        raise HubError(f"{who} answers each window after it has passed: {problem}")
    if desc.cycle_ms is not None and desc.cycle_ms > period_ms:
        return (
            f"{who}: its own I/O cycle takes {desc.cycle_ms:.1f} ms, longer than the "
            f"period of {period_ms:g} ms: each step gets its freshest reading, up to "
            f"~{desc.cycle_ms:.0f} ms old (the readings' ages are recorded)"
        )
    return None
