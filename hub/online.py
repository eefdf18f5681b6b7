"""The hub's side of live burst detection (``[online]``): the burst observer's run.

The detection itself runs in the burst observer (:mod:`hub.burst_observer`), a process of
its own beside the loop. :class:`OnlineAnalysis` is what the hub does for it: it starts
the observer (``online.launch = "local"``), gives it the run, leaves it the culture's
SpikeBatches to ask for, counts its reports and records the network bursts they carry,
notes when it vanishes and comes back, and asks for its final report after the last step.

The loop never waits for it: an observer that falls behind, freezes or vanishes reports
later, or its final report counts the steps it never had (the manifest's
``online_analysis``: ``complete`` or ``incomplete``).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from pathlib import Path

from hub import wire
from hub.burst_observer import NAME, OnlineTally
from hub.config import ExperimentConfig
from hub.errors import HubError
from hub.launch import LocalProcess, last_line, start_burst_observer
from hub.link import HubLink
from hub.protocol import (
    BurstReport,
    ObservedSpikes,
    ObserverEnd,
    ObserverStart,
    ProtocolError,
)
from hub.roster import ANNOUNCE_TIMEOUT_S, run_replies

log = logging.getLogger(__name__)

# The culture's spikes go to the burst observer every this many seconds of wall time, many
# steps in one put: in realtime soon enough for a live display to show a network burst
# under way within a frame or two; in lockstep a put and a wake-up of the observer a step
# (or even every 100 ms of run time, at thousands of steps a second) would cost the loop.
FORWARD_S = {"realtime": 0.03, "lockstep": 0.05}
# The forwarded spikes kept for the burst observer to ask for: one that stalls (frozen,
# swapped out) or whose lease lapsed catches up on its return if it was gone less than this.
OBSERVER_KEEP_S = 10.0
# The longest the hub waits for the burst observer's final report (one that fell behind
# catches up first; it answers within seconds of its last spikes coming otherwise).
OBSERVER_END_TIMEOUT_S = 60.0
# At the run's end, the hub's own observer unanswered is asked again this often, and waited
# for while away (its lease lapsed: back within milliseconds of running again) this long.
END_ASK_AGAIN_S, END_ABSENT_S = 0.05, 3.0
# The observer's participant name on the bus (its liveliness token: ``observer/<NAME>``)
PARTICIPANT = ("observer", NAME)


class OnlineAnalysis:
    """The burst observer of one run, as the hub sees it.

    Parameters
    ----------
    cfg : ExperimentConfig
        The run's experiment (``online``, ``bus``, ``loop.mode`` and ``loop.cpus``).
    run_id : str
    record_event : callable
        ``record_event(name, **details)``: an event in the run's record.
    step_now : callable
        The step under way (what the events it records are stamped with).

    Attributes
    ----------
    tally : OnlineTally
        The observer's reports so far: the counts, the latest network bursts, whether the
        final one came (and if not, why: ``tally.lost``).
    key : bytes
        The key that seals what the hub and the observer send each other.
    process : LocalProcess or None
        The observer the hub started (``online.launch = "local"``), once :meth:`start`.
    """

    def __init__(
        self,
        cfg: ExperimentConfig,
        run_id: str,
        record_event: Callable[..., None],
        step_now: Callable[[], int],
    ):
        self.cfg = cfg
        self.run_id = run_id
        self.tally = OnlineTally()
        self.key = wire.new_key()
        self.process: LocalProcess | None = None
        self.forward_s = FORWARD_S[cfg.loop.mode]
        self.forwarded_at = 0.0  # time.monotonic() of the last forward
        # the culture's SpikeBatches taken and not forwarded yet (every forward_s; in
        # realtime after a step, in the slack before the next)
        self.pending: list[bytes] = []
        self._gone: tuple[float, int] | None = None  # (since, step) while it is away
        self._record_event = record_event
        self._step_now = step_now
        self._link: HubLink | None = None

    def start(self, log_dir: Path | None) -> LocalProcess | None:
        """Start the observer as a child process if ``online.launch = "local"`` (its log:
        ``observer.log`` in ``log_dir``); the process, or None."""
        if self.cfg.online.launch == "local":
            self.process = start_burst_observer(self.cfg.bus, log_dir, self.cfg.loop.cpus)
        return self.process

    def exited_early(self) -> HubError | None:
        """The error to raise if the observer the hub started has ended before the run."""
        proc = self.process
        if proc is None or proc.popen.poll() is None:
            return None
        return HubError(
            f"the burst observer that the hub started ended before the run, with exit "
            f"status {proc.popen.returncode}{last_line(proc.log_path)} (its log: "
            f"{proc.log_path or 'none'}; online.enabled = false runs without it)"
        )

    def announce(self, link: HubLink, n_steps: int, channel) -> None:
        """Give the observer the run: the culture's channel ids, the detector's
        parameters, the sealing key; and keep the spikes for it to ask for.

        Parameters
        ----------
        link : HubLink
            The hub's declarations for the run (the observer's exchange is added to it).
        n_steps : int
            The run's steps.
        channel : array of uint32
            The culture's channel ids (its description's).

        Raises
        ------
        HubError
            It did not answer, or refused the run.
        """
        online = self.cfg.online
        start = ObserverStart(
            run=self.run_id,
            n_steps=n_steps,
            channel=channel,
            key=self.key,
            burst=dict(online.burst),
            network=dict(online.network),
        )
        self._link = link
        link.watch_observer(NAME, self.key, keep=math.ceil(OBSERVER_KEEP_S / self.forward_s))
        answers = run_replies(link, link.keys.observer_run(NAME), start, ANNOUNCE_TIMEOUT_S)
        if not answers:
            raise HubError("the burst observer did not answer the run's announcement")
        refused = [a.reason for a in answers if not a.ok or a.run != self.run_id]
        if refused:
            raise HubError(f"the burst observer refused the run: {refused[0]}")
        self._record_event("run_taken", role="observer", id=NAME, run=self.run_id)
        self.tally.announced = True

    def forward(self) -> None:
        """The culture's SpikeBatches taken since the last forward, to the observer."""
        if self.pending and self._link is not None:
            self.forwarded_at = time.monotonic()
            batches, self.pending = self.pending, []
            self._link.forward_spikes(ObservedSpikes(run=self.run_id, batches=batches).encode())

    def take_report(self, report: BurstReport) -> None:
        """Count one of the observer's reports and record each network burst it found."""
        if report.run != self.run_id:
            return
        step = self._step_now()
        tally = self.tally
        was_under_way = tally.onset_ms
        rows = tally.take(report)
        if report.onset_ms is not None and was_under_way is None:
            # what a live display was told, and when
            self._record_event("network_burst_under_way", onset_ms=report.onset_ms, at_step=step)
        for start, end, n_channels, core_start, core_end in rows:
            self._record_event(
                "network_burst",
                start_ms=start,
                end_ms=end,
                n_channels=n_channels,
                core_start_ms=core_start,
                core_end_ms=core_end,
                at_step=step,
            )

    def came_or_went(self, present: bool) -> dict | None:
        """The observer vanished, or is back, during the steps: the rejoin's entry for the
        manifest when it is back, else None.

        Live analysis only: the loop goes on and the record keeps every spike. Back, the
        observer asks for the spikes after the last it had; those the hub no longer keeps
        (``OBSERVER_KEEP_S``) its final report counts as missing steps.
        """
        tally, step = self.tally, self._step_now()
        if tally.final:
            return None
        if not present:
            log.warning(
                "the burst observer vanished at step %d: live bursts wait for its return "
                "(the hub keeps %g s of spikes for it)", step, OBSERVER_KEEP_S,
            )  # fmt: skip
            tally.lost = f"the burst observer vanished at step {step}"
            self._gone = (time.monotonic(), step)
            return None
        if self._gone is None:
            return None
        since, gone_at = self._gone
        self._gone = None
        tally.lost = ""
        entry = {"role": "observer", "id": NAME, "gone_at_step": gone_at}
        entry.update(at_step=step, gap_s=round(time.monotonic() - since, 3))
        self._record_event("rejoined", **entry)
        log.warning(
            "the burst observer is back at step %d after %.2f s: live bursts go on (its "
            "final report says whether it had every step)",
            step, entry["gap_s"],
        )  # fmt: skip
        return entry

    def end(
        self,
        steps_done: int,
        *,
        there: Callable[[], bool],
        take_waiting: Callable[[], None],
    ) -> None:
        """After the steps: ask the observer for its final report (every step's spikes
        analysed, every burst still open completed), and count it; waits up to
        :data:`OBSERVER_END_TIMEOUT_S`. Without it, ``tally.lost`` says why.

        An observer the hub started whose process still runs is asked again until it
        answers: one whose lease lapsed at the run's end (frozen or starved before or
        while it was asked: no answer, or its question ended empty as the lease lapsed) is
        back within milliseconds of running again, its run kept, and its final report
        counts the steps it missed. One that stays away longer than
        :data:`END_ABSENT_S` is not waited for.

        Parameters
        ----------
        steps_done : int
            The steps the run made (those the observer should have had).
        there : callable
            ``there()``: whether the observer's token is on the bus now.
        take_waiting : callable
            Handles what came before the question (the observer's reports, its going and
            its return; called with no argument).
        """
        tally = self.tally
        if tally.final:
            return
        if not tally.announced:
            tally.lost = "the run ended before the burst observer had it"
            return
        self.forward()  # the last steps'
        take_waiting()
        end = ObserverEnd(run=self.run_id, steps=steps_done).encode()
        link = self._link
        now = time.monotonic()
        deadline, absent_since, asked = now + OBSERVER_END_TIMEOUT_S, None, False
        while True:
            present = there()
            if present:
                asked, absent_since = True, None
            elif absent_since is None:
                absent_since = time.monotonic()
            # Its token's going may be seen after its return (the old link's close): one
            # the hub started, its process alive, is asked whatever its token says (a
            # question that nothing answers ends at once).
            if present or self._may_answer():
                left_s = max(deadline - time.monotonic(), END_ASK_AGAIN_S)
                for raw in link.query(link.keys.observer_run(NAME), end, timeout_s=left_s):
                    try:
                        self.take_report(BurstReport.decode(raw))
                    except ProtocolError:
                        continue
            now = time.monotonic()
            away_too_long = absent_since is not None and now - absent_since > END_ABSENT_S
            if tally.final or not self._may_answer() or now >= deadline or away_too_long:
                break
            time.sleep(END_ASK_AGAIN_S)
            take_waiting()
        if not tally.final:
            why = "did not answer" if asked else "was not there"
            tally.lost = tally.lost or f"the burst observer {why} at the run's end"

    def _may_answer(self) -> bool:
        """Whether the observer may still answer after a question that got no final report:
        one the hub started whose process still runs (one run elsewhere cannot be told
        from one gone for good)."""
        proc = self.process
        return proc is not None and proc.popen.poll() is None
