"""The run's endpoints as the hub takes them in, and lets them go.

Before the steps the hub waits until every endpoint (and the burst observer, with live
burst detection) is on the bus, asks each to describe itself (its replies are checked
against that description) and gives each the run: its id, timing and a key of its own
(contract v2). An endpoint that comes back during the steps is described and given the
run again. At the end, each one still there is told the run is over (it makes itself
safe) and asked for its own counters. The questions themselves are :mod:`hub.roster`'s.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from hub import wire
from hub.errors import HubError
from hub.online import PARTICIPANT as OBSERVER
from hub.protocol import ROLES, Description, RunStart
from hub.replies import ReplyChecker
from hub.report import steps_share
from hub.roster import Roster, check_fits_loop

if TYPE_CHECKING:
    from hub.config import ExperimentConfig
    from hub.online import OnlineAnalysis
    from hub.steps import Standing

log = logging.getLogger(__name__)


class Participants:
    """Awaits, describes, admits and dismisses the run's endpoints.

    Parameters
    ----------
    cfg : ExperimentConfig
        The run's experiment (its endpoints' ids, ``[loop]`` and ``[bus]``).
    run_id : str
    standing : Standing
        Who is on the bus, and whether a stop came while waiting.
    online : OnlineAnalysis or None
        The burst observer's run (awaited too, when there is one).
    record_event : callable
        ``record_event(name, **details)``: an event in the run's record.

    Attributes
    ----------
    roster : Roster or None
        The questions to the endpoints over the hub's link, once the session is open.
    ids : dict
        Role → the id of the run's body and culture.
    run_keys : dict
        Role → the key that seals what the hub and that endpoint send each other.
    checker : ReplyChecker
        What each endpoint's replies are checked against: its description, the run.
    descriptions : dict
        Role → its :class:`~hub.protocol.Description`, once described.
    where : dict
        Role → what the manifest keeps of where it runs (host, clock offset).
    """

    def __init__(
        self,
        cfg: ExperimentConfig,
        run_id: str,
        standing: Standing,
        online: OnlineAnalysis | None,
        record_event: Callable[..., None],
    ):
        self.cfg, self.run_id, self.standing = cfg, run_id, standing
        self.online, self._record_event = online, record_event
        self.roster: Roster | None = None
        self.ids = {role: cfg.endpoint(role).id for role in ROLES}
        self.run_keys = {role: wire.new_key() for role in ROLES}
        self.checker = ReplyChecker(run_id, cfg.loop.period_ms / 1e3)
        self.descriptions: dict[str, Description] = {}
        self.where: dict[str, dict] = {}
        self._start_unix_s: float | None = None  # as announced to the endpoints

    def await_all(self, next_event: Callable[[float], object]) -> None:
        """Handle events (``next_event(until)``) until every endpoint, and the burst observer
        with live burst detection, is on the bus.

        Raises
        ------
        HubError
            One did not come within ``loop.wait_timeout_s``, the observer the hub started
            ended, or a stop came meanwhile (:class:`~hub.steps.StoppedBeforeSteps`: the
            user's).
        """
        cfg, alive = self.cfg, self.standing.alive
        needed = set(self.ids.items()) | ({OBSERVER} if self.online is not None else set())
        start = time.monotonic()
        deadline = start + cfg.loop.wait_timeout_s
        next_note = start
        while not needed <= alive:
            missing = needed - alive
            if time.monotonic() >= next_note:  # say at once what is awaited, then every 5 s
                log.info(
                    "waiting for %s on session %r (%.0f s of %g s): each builds its model "
                    "before it appears; a simulator's first run also compiles its kernels%s",
                    _named(missing), cfg.bus.session, time.monotonic() - start,
                    cfg.loop.wait_timeout_s, self.roster.elsewhere(missing),
                )  # fmt: skip
                next_note += 5.0
            self.standing.check_stop("endpoints")
            if OBSERVER in missing:  # one that ended will not come: say so now
                exited = self.online.exited_early()
                if exited is not None:
                    raise exited
            if time.monotonic() >= deadline:
                hint = ""
                if OBSERVER in missing:
                    hint = (
                        '; with online.launch = "external" start it with \'neuvision observe '
                        'bursts CONFIG --connect HOST\' ("local": the hub starts it, see '
                        "observer.log in the run folder); online.enabled = false runs "
                        "without live burst detection"
                    )
                raise HubError(
                    f"endpoint(s) {_named(missing)} did not appear on session "
                    f"{cfg.bus.session!r} within {cfg.loop.wait_timeout_s} s (listening on "
                    f"{', '.join(cfg.bus.listen)}){hint}{self.roster.elsewhere(missing)}"
                )
            next_event(min(deadline, time.monotonic() + 0.1))

    def describe_all(self) -> None:
        """Ask each endpoint to describe itself (see :meth:`describe`)."""
        for role in self.ids:
            self.describe(role)

    def describe(self, role: str) -> None:
        """Ask ``role`` to describe itself; keep what its replies are checked against.

        Raises
        ------
        HubError
            No description or a bad one, or one that cannot take this run's loop.
        """
        i = self.ids[role]
        desc, where = self.roster.describe(role, i)
        self.where[role] = where
        warning = check_fits_loop(desc, self.cfg.loop)
        if warning:
            log.warning("%s", warning)
            self._record_event("warning", role=desc.role, id=desc.id, reason=warning)
        self.descriptions[desc.role] = desc
        self.checker.take_description(desc)
        self._record_event("described", role=role, id=i, kind=desc.kind)

    def announce_all(self) -> None:
        """Give each endpoint the run (see :meth:`announce`)."""
        for role in self.ids:
            self.announce(role)

    def announce(self, role: str) -> None:
        """Give ``role`` the run: its id, timing and that endpoint's key (again when it
        rejoins: the same id, timing and key).

        Raises
        ------
        HubError
            It did not answer, or refused.
        """
        cfg, i = self.cfg, self.ids[role]
        if self._start_unix_s is None:
            self._start_unix_s = time.time()
        start = RunStart(
            run=self.run_id,
            period_ms=float(cfg.loop.period_ms),
            n_steps=cfg.n_steps,
            mode=cfg.loop.mode,
            start_unix_s=self._start_unix_s,
            deadline_ms=cfg.loop.deadline_s * 1e3,
            key=self.run_keys[role],
            seed=cfg.experiment.seed,
        )
        self.roster.announce(role, i, start)
        self._record_event("run_taken", role=role, id=i, run=self.run_id)

    def readmit(self, role: str) -> None:
        """``role`` came back during the steps: describe it and give it the run again (it
        starts from its model's or device's start)."""
        self.describe(role)
        self.announce(role)

    def hold(self, hold: bool) -> dict[str, bool]:
        """Tell each endpoint the run is paused (``hold``) or resumed: whether each
        acknowledged, by role."""
        return self.roster.hold(list(self.ids.items()), self.run_id, hold)

    def manifest_entries(self) -> dict[str, dict]:
        """What the manifest keeps of each endpoint described: its kind and id, where it
        runs, and its own counters over the steps (drops, steps, busy and CPU time), asked
        now of those still there."""
        final = self.roster.final_counters(self._there())
        return {
            r: {"kind": d.kind, "id": d.id, **self.where.get(r, {}), **steps_share(d, final)}
            for r, d in self.descriptions.items()
        }

    def end(self, outcome: str) -> None:
        """Tell each endpoint still there that the run is over (it makes itself safe)."""
        there = [(r, i) for r, i in self._there() if r in self.descriptions]
        self.roster.end(there, self.run_id, outcome)

    def _there(self) -> list[tuple[str, str]]:
        return [(r, i) for r, i in self.ids.items() if (r, i) in self.standing.alive]


def _named(who: set[tuple[str, str]]) -> str:
    return ", ".join(f"{r}/{i}" for r, i in sorted(who))
