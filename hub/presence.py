"""Who is on the bus during a run, and what their coming and going means.

Each participant declares a liveliness token (``alive/<role>/<id>``); the hub sees each
come and go. During the steps an endpoint whose token vanishes is dead
(``policy.endpoint_death``: the run stops, or goes on without it), unless
``policy.rejoin_s`` lets it come back within that long: a restarted process, a dropped
link (docs/remote.md). The burst observer may vanish and come back at any time: the loop
goes on without it (:mod:`hub.online`). A death seen just after the hub itself did not run
for a while (frozen, starved of CPU) is the hub's doing, and said so: the run's fault, or,
with ``policy.rejoin_s``, in the log while the endpoint is awaited back.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from hub.errors import EndpointDied, HubError
from hub.online import PARTICIPANT as OBSERVER
from hub.protocol import ROLES

if TYPE_CHECKING:
    from hub.config import ExperimentConfig
    from hub.ledger import Ledger
    from hub.online import OnlineAnalysis
    from hub.steps import Scheduler, Standing

log = logging.getLogger(__name__)


class Presence:
    """The run's participants on the bus: their liveliness, deaths and rejoins.

    Parameters
    ----------
    cfg : ExperimentConfig
        The run's experiment (``policy``, ``bus.lease_ms``, ``record.flush_s``).
    standing : Standing
        Where the run stands; its ``alive`` and ``awaited`` are kept here.
    ledger : Ledger
        The run's replies: whose were stood in for, one after another, since when.
    steps : Scheduler
        The run's scheduler: the step under way (``k``), told of an endpoint's return.
    online : OnlineAnalysis or None
        The burst observer's run, told when the observer goes and comes back.
    readmit : callable
        ``readmit(role)``: describe an endpoint that came back and give it the run again.
    record_event : callable
        ``record_event(name, **details)``: an event in the run's record.

    Attributes
    ----------
    rejoins : list of dict
        Each return during the steps (the manifest's ``rejoins``).
    """

    def __init__(
        self,
        cfg: ExperimentConfig,
        standing: Standing,
        ledger: Ledger,
        steps: Scheduler,
        online: OnlineAnalysis | None,
        readmit: Callable[[str], None],
        record_event: Callable[..., None],
    ):
        self.cfg, self.standing, self.steps, self.online = cfg, standing, steps, online
        self.ledger = ledger
        self._silenced: set[str] = set()  # roles taken for dead for their silence
        self.ids = {role: cfg.endpoint(role).id for role in ROLES}
        self._keys = cfg.bus.keys
        self._readmit, self._record_event = readmit, record_event
        self.rejoins: list[dict] = []
        # The loop's thread wakes at least every record.flush_s; a longer gap means the hub
        # itself did not run (frozen, starved): (when it ended, how long it was).
        self._last_wake = time.monotonic()
        self._stall: tuple[float, float] = (-float("inf"), 0.0)
        self._stepping = False  # gaps count once the steps started (steps_start)

    def seen(self, key: str, present: bool) -> None:
        """A liveliness token came or went.

        Parameters
        ----------
        key : str
            The token's key (an endpoint's or the burst observer's).
        present : bool
            It came (True) or went.

        Raises
        ------
        EndpointDied
            An endpoint of the run died during the steps (``policy.endpoint_death = "stop"``).
        HubError
            It vanished while the hub itself was not running (its lease lapsed meanwhile).
        """
        parsed = self._keys.parse_alive(key)
        if parsed is None:
            return
        standing, policy = self.standing, self.cfg.policy
        was = parsed in standing.alive
        (standing.alive.add if present else standing.alive.discard)(parsed)
        if was == present:
            return
        self._record_event("alive" if present else "dead", role=parsed[0], id=parsed[1])
        stepping = standing.state in ("running", "paused")
        if parsed == OBSERVER and self.online is not None:
            entry = self.online.came_or_went(present) if stepping else None
            if entry is not None:
                self.rejoins.append(entry)
            return
        role, k = parsed[0], self.steps.k
        required = role in ROLES and self.ids[role] == parsed[1]
        if present and required and role in standing.awaited:
            return self._rejoin(role)
        if present or not required or not stepping:
            return
        stalled_s = self._hub_stalled_s()
        stall = (
            f"the hub itself stopped running for {stalled_s:.1f} s (frozen or starved of CPU) "
            f"at step {k}: {role}/{parsed[1]}'s lease lapsed meanwhile"
        )
        if policy.rejoin_s > 0:  # whatever the cause, it may come back
            log.warning(
                "%s/%s vanished at step %d%s: it may rejoin within %g s (policy.rejoin_s)",
                *parsed, k, f" ({stall})" if stalled_s else "", policy.rejoin_s,
            )  # fmt: skip
            standing.awaited[role] = (time.monotonic(), k)
            return
        if stalled_s:
            raise HubError(stall)
        self._dead(role)

    def check_deadlines(self) -> None:
        """An endpoint awaited back longer than ``policy.rejoin_s`` is dead.

        Raises
        ------
        EndpointDied
            With ``policy.endpoint_death = "stop"``.
        """
        now = time.monotonic()
        for role, (since, _) in list(self.standing.awaited.items()):
            if now - since > self.cfg.policy.rejoin_s:
                del self.standing.awaited[role]
                self._record_event("rejoin_expired", role=role, id=self.ids[role])
                self._dead(role)

    def check_silent(self) -> None:
        """An endpoint still on the bus whose replies were all stood in for, one after
        another, for ``policy.silent_s`` is taken for dead: hung, or another process took
        its name on the bus (Zenoh keeps one token of a name while any holds it, so the
        death of the one that had the run is not seen).

        Raises
        ------
        EndpointDied
            With ``policy.endpoint_death = "stop"``.
        """
        silent_s, standing = self.cfg.policy.silent_s, self.standing
        if not silent_s or standing.state != "running":
            return
        self._silenced &= self.ledger.silent_since.keys()  # those that answered since
        for role in self.ledger.silent(time.monotonic(), silent_s):
            on_bus = (role, self.ids[role]) in standing.alive
            if not on_bus or role in standing.awaited or role in self._silenced:
                continue
            self._silenced.add(role)
            self._record_event("silent", role=role, id=self.ids[role], silent_s=silent_s)
            self._dead(role, why=(
                f"it answered none of its inputs for {silent_s:g} s though its token is on "
                f"the bus: hung, or another process took its name; policy.silent_s"
            ))  # fmt: skip

    def note_wake(self) -> None:
        """The loop's thread woke: keep the last gap in its running longer than its longest
        wait (``record.flush_s``) and a quarter lease, less than a lease lapsing takes.
        Only gaps once the steps started count (:meth:`steps_start`): before them the
        thread works between its waits (the endpoints described, the run announced)."""
        now = time.monotonic()
        gap_s = now - self._last_wake
        self._last_wake = now
        if self._stepping and gap_s > self.cfg.record.flush_s + self.cfg.bus.lease_ms / 4e3:
            self._stall = (now, gap_s)

    def steps_start(self) -> None:
        """The steps start now: gaps in the loop's running count from here."""
        self._last_wake, self._stepping = time.monotonic(), True

    def _hub_stalled_s(self) -> float:
        """How long the hub's loop did not run, if that ended within the last two leases
        (an endpoint's lease that lapsed then lapsed while the hub was not running: seen
        at most a lease after it ran again); 0.0 otherwise."""
        ended, gap_s = self._stall
        return gap_s if time.monotonic() - ended < 2 * self.cfg.bus.lease_ms / 1e3 else 0.0

    def _dead(self, role: str, why: str = "its liveliness token vanished") -> None:
        """An endpoint is gone for good (``why``: how it was seen): ``policy.endpoint_death``
        applies."""
        i, k, death = self.ids[role], self.steps.k, self.cfg.policy.endpoint_death
        if death == "stop":
            raise EndpointDied(role, i, k, why)  # logged once, where the run ends
        log.error("%s/%s died at step %d (%s); the run goes on (policy.endpoint_death = %r)",
                  role, i, k, why, death)  # fmt: skip

    def _rejoin(self, role: str) -> None:
        """An endpoint that vanished is back within ``policy.rejoin_s``: described and given
        the run again (same id and key; it starts from its model's or device's start)."""
        since, gone_at = self.standing.awaited.pop(role)
        self.ledger.silent_since.pop(role, None)  # a new start: its silence counts again
        self._silenced.discard(role)
        i = self.ids[role]
        self._readmit(role)
        gap_s = time.monotonic() - since
        entry = {"role": role, "id": i, "gone_at_step": gone_at, "at_step": self.steps.k}
        entry["gap_s"] = round(gap_s, 3)
        self.rejoins.append(entry)
        self._record_event("rejoined", **entry)
        log.warning("%s/%s rejoined at step %d after %.2f s", role, i, self.steps.k, gap_s)
        self.steps.rejoined(role)
