"""What observers see of a run while it goes: its status, views for live displays, progress.

The status (:class:`~hub.protocol.HubStatus`) is published ``loop.status_hz`` times a
second and given on request; a progress callback gets the same figures. Views
(:class:`~hub.protocol.HubView`, :mod:`hub.view`) are built ``loop.view_hz`` times a second
while anyone asks for them, and left on the link for the displays that ask (docs/contract.md,
"For observers"). When each is built is the loop's choice (:mod:`hub.lockstep`,
:mod:`hub.realtime`): never where it could hold up a step.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from hub.protocol import HubStatus

if TYPE_CHECKING:
    from hub.burst_observer import OnlineTally
    from hub.config import ExperimentConfig
    from hub.ledger import Ledger
    from hub.link import HubLink
    from hub.report import LoopTimes
    from hub.steps import Scheduler, Standing
    from hub.traffic import Traffic

# How often the hub looks whether anyone asks for views, while no one does.
LOOK_S = 0.25


@dataclass
class Progress:
    """What a progress display needs, given after each status."""

    step: int
    n_steps: int
    t_s: float
    wall_s: float
    steps_per_s: float
    late_steps: int
    state: str


class Telemetry:
    """Builds and publishes a run's status and views, and calls its progress callback.

    Parameters
    ----------
    cfg : ExperimentConfig
        The run's experiment (``loop``: its period, mode, ``status_hz`` and ``view_hz``).
    run_id : str
    standing : Standing
        Where the run stands (its state, why it stops, who is on the bus).
    steps : Scheduler
        The run's scheduler: the step under way and the steps done.
    ledger : Ledger
        The late, missing and dropped counts; the parts of steps gone missing.
    times : LoopTimes
        The steps' timing.
    traffic : Traffic
        The run's messages: each endpoint's latest round trip, and the view they fill.
    tally : OnlineTally or None
        The burst observer's reports so far (None: no live burst detection).
    progress : callable or None
        Called with a :class:`Progress` at each status.

    Attributes
    ----------
    link : HubLink or None
        Where status and views go, once the session is open.
    status_due_at, view_due_at : float
        When (monotonic) the next status and the next view fall due.
    """

    def __init__(
        self,
        cfg: ExperimentConfig,
        run_id: str,
        standing: Standing,
        steps: Scheduler,
        ledger: Ledger,
        times: LoopTimes,
        traffic: Traffic,
        tally: OnlineTally | None,
        progress: Callable[[Progress], None] | None,
    ):
        self.cfg, self.run_id, self.standing, self.steps = cfg, run_id, standing, steps
        self.ledger, self.times, self.tally, self.progress = ledger, times, tally, progress
        self.view, self.round_trip_ms = traffic.view, traffic.round_trip_ms
        self.link: HubLink | None = None
        self.status_due_at = self.view_due_at = 0.0

    def status(self) -> HubStatus:
        """The run's status now (what ``hub/status`` carries)."""
        cfg, ledger, times, tally = self.cfg, self.ledger, self.times, self.tally
        wall, running = times.wall_s(), times.running_s()
        done = self.steps.k_done
        ended = self.standing.ended
        return HubStatus(
            step=self.steps.k,
            t_s=done * cfg.loop.period_ms / 1e3,
            mode=cfg.loop.mode,
            state=self.standing.state,
            late=dict(ledger.late),
            missing={r: len(s) for r, s in ledger.missed.items() if s},
            dropped={r: sum(c.values()) for r, c in ledger.dropped.items()},
            alive=sorted(f"{r}/{i}" for r, i in self.standing.alive),
            wall_s=wall,
            steps_per_s=done / running if running > 0 else 0.0,
            extra={
                "late_steps": times.late_steps,
                "single_channel_bursts": tally.bursts if tally else 0,
                "network_bursts": tally.network_bursts if tally else 0,
                "network_burst_under_way_ms": tally.onset_ms if tally else None,
                # [onset_ms, last seen under way (ms)] each, the latest 8
                "recent_network_bursts_under_way": [
                    [round(v, 3) for v in u] for u in (tally.under_way if tally else ())
                ],
                "round_trip_ms": dict(self.round_trip_ms),
                # a stop asked for (or decided) takes effect after the current step
                "stop_reason": self.standing.stop_reason or "",
                # for observers (the dashboard, docs/dashboard.md)
                "run": self.run_id,
                "period_ms": float(cfg.loop.period_ms),
                "n_steps": cfg.n_steps,
                # [start_ms, end_ms, n_channels, core_start_ms, core_end_ms] each
                "recent_network_bursts": [
                    [round(v, 3) for v in nb] for nb in (tally.recent if tally else ())
                ],
                **times.lateness_now(done),
                # how the run ended: in the final status (state "stopped")
                **({"outcome": ended[0], "reason": ended[1]} if ended else {}),
            },
        )

    def publish_status(self, now: float, *, progress: bool = True) -> None:
        """Publish the status, and the next falls due ``1 / loop.status_hz`` later.

        Parameters
        ----------
        now : float
            The time (monotonic, s).
        progress : bool
            Also give it to the progress callback (the terminal's line).
        """
        self.status_due_at = now + 1.0 / self.cfg.loop.status_hz
        status = self.status()
        if self.link is not None:
            self.link.publish_status(status.encode())
        if progress and self.progress:
            self.progress(
                Progress(status.step, self.cfg.n_steps, status.t_s, status.wall_s,
                         status.steps_per_s, self.times.late_steps, status.state)
            )  # fmt: skip

    def publish_view(self, now: float) -> None:
        """A view for live displays, if anyone asks for them and the loop moved; whether
        anyone asks is looked at every ``LOOK_S`` meanwhile."""
        hz = self.cfg.loop.view_hz
        stranded = self.ledger.stranded
        if self.link is None or not hz:
            self.view_due_at = math.inf
            stranded.clear()
            return
        view = self.view
        view.watch(self.link.view_observed())
        for part in stranded:  # of steps that went missing: shown as late
            view.took(part)
        stranded.clear()
        self.view_due_at = now + (1.0 / hz if view.observed else LOOK_S)
        built = view.build(self.steps.k_done)
        if built is not None:
            self.link.publish_view(built.encode())
