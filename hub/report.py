"""What a run reports of itself: where its time went, and what it counted.

Plain data, no bus: the schedulers write each step's wall time and lateness into
:class:`LoopTimes`; :meth:`LoopTimes.report` and :func:`counts` make the manifest's
``timing`` and ``counts`` entries; :func:`steps_share` an endpoint's own counters for the
steps alone.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from hub.protocol import Description
from hub.scheduling import CpusAwake, Scheduling, available_cpus


@dataclass
class LoopTimes:
    """The wall and CPU time of a run's steps.

    Attributes
    ----------
    step_wall_s, lateness_s : float arrays, one value per step
        How long each step took; in realtime, how late each step started (NaN: not yet).
    late_steps : int
        Steps that missed a reply's deadline or started late.
    waiting_s : float
        Time the loop's thread spent blocked, waiting for events.
    direct_busy_s : float
        Lockstep: time spent on replies in the threads they came on.
    t_start, cpu_start_s : float
        Monotonic and process CPU time when the steps began (``t_start`` 0: not yet).
    t_stop, cpu_stop_s : float
        The same when the steps ended (``t_stop`` 0: not yet): the run's figures cover its
        steps, not what the hub does after them (the body's final stop, the endpoints'
        counters, the observer's last report, a live display's last view).
    paused_s : float
        Time paused by control, over the pauses that ended (:meth:`pause`, :meth:`resume`):
        the realtime schedule is shifted by it, and the run's pace is taken without it.
    """

    mode: str
    period_ms: float
    step_wall_s: np.ndarray
    lateness_s: np.ndarray
    late_steps: int = 0
    waiting_s: float = 0.0
    direct_busy_s: float = 0.0
    t_start: float = 0.0
    cpu_start_s: float = field(default=0.0)
    t_stop: float = 0.0
    cpu_stop_s: float = 0.0
    paused_s: float = 0.0
    _pause_started: float = field(default=0.0, repr=False)  # 0: not paused
    # role -> per step: from the input's put to its reply's arrival (NaN: none came)
    round_trip_s: dict[str, np.ndarray] = field(default_factory=dict)
    _lateness_seen: int = field(default=0, repr=False)  # steps scanned by lateness_now
    _lateness_max_s: float = field(default=float("nan"), repr=False)

    @classmethod
    def for_run(cls, mode: str, period_ms: float, n_steps: int) -> LoopTimes:
        """The times of a run not started yet: every per-step value NaN.

        Parameters
        ----------
        mode : str
            ``loop.mode`` (``"lockstep"`` or ``"realtime"``).
        period_ms : float
            The loop's period.
        n_steps : int
            The run's steps (the length of the per-step arrays).
        """
        times = cls(mode, period_ms, np.full(n_steps, np.nan), np.full(n_steps, np.nan))
        times.round_trip_s = {role: np.full(n_steps, np.nan) for role in ("body", "culture")}
        return times

    def round_trip_ms(self, steps: int) -> dict[str, dict[str, float]]:
        """Each endpoint's reply round trip over the first ``steps`` steps: median, p99, max
        (ms; its replies that came, late ones included)."""
        out = {}
        for role, rtt in self.round_trip_s.items():
            ms = rtt[:steps][~np.isnan(rtt[:steps])] * 1e3
            if ms.size:
                out[role] = {
                    "median": float(np.median(ms)),
                    "p99": float(np.percentile(ms, 99)),
                    "max": float(ms.max()),
                }
        return out

    def steps_took(self, first: int, end: int, wall_s: float) -> None:
        """Steps ``first`` to ``end - 1`` took ``wall_s`` together (shared evenly).

        Parameters
        ----------
        first, end : int
            The steps completed: ``first`` to ``end - 1``.
        wall_s : float
            The wall time they took together (lockstep: since the step before completed).
        """
        if end == first + 1:  # a numpy scalar store, not a slice's
            self.step_wall_s[first] = wall_s
        else:
            self.step_wall_s[first:end] = wall_s / (end - first)

    def start(self) -> None:
        """The steps begin now."""
        self.t_start = time.monotonic()
        self.cpu_start_s = time.process_time()
        self.waiting_s = self.direct_busy_s = 0.0

    def stop(self, not_before: float = 0.0) -> None:
        """The steps ended now, or at ``not_before`` if later (realtime: the end of the last
        step's period); a pause under way ends with them."""
        if self.t_start and not self.t_stop:
            self.t_stop = max(time.monotonic(), not_before)
            self.cpu_stop_s = time.process_time()
            self.resume(at=self.t_stop)

    def pause(self) -> None:
        """The steps are held from now (``ctl pause``)."""
        if not self._pause_started:
            self._pause_started = time.monotonic()

    def resume(self, at: float | None = None) -> None:
        """The steps go on from now (or ``at``): the pause is added to :attr:`paused_s`."""
        if self._pause_started:
            end = time.monotonic() if at is None else at
            self.paused_s += max(end - self._pause_started, 0.0)
            self._pause_started = 0.0

    def wall_s(self) -> float:
        """Wall time of the steps, pauses included: since they began, until they ended (0
        before)."""
        if not self.t_start:
            return 0.0
        return (self.t_stop or time.monotonic()) - self.t_start

    def paused_total_s(self) -> float:
        """Time paused so far, a pause under way included."""
        ongoing = time.monotonic() - self._pause_started if self._pause_started else 0.0
        return self.paused_s + ongoing

    def running_s(self) -> float:
        """Wall time of the steps less the time paused: what the run's pace is taken over."""
        return max(self.wall_s() - self.paused_total_s(), 0.0)

    def cpu_s(self) -> float:
        """The hub's process CPU time over the steps (0 before)."""
        if not self.t_start:
            return 0.0
        return (self.cpu_stop_s if self.t_stop else time.process_time()) - self.cpu_start_s

    def lateness_now(self, steps: int) -> dict:
        """Realtime: how late the last of ``steps`` steps started and the most so far, in ms
        (``lateness_ms``, ``lateness_ms_max``), for the hub's status; ``{}`` before a step
        or in lockstep. Each call scans only the steps since the last one."""
        if self.mode != "realtime" or steps < 1:
            return {}
        new = self.lateness_s[self._lateness_seen : steps]
        new = new[~np.isnan(new)]
        if new.size:
            self._lateness_max_s = float(np.fmax(self._lateness_max_s, new.max()))
        self._lateness_seen = max(self._lateness_seen, steps)
        last = float(self.lateness_s[steps - 1])
        out = {}
        if last == last:  # not NaN
            out["lateness_ms"] = last * 1e3
        if self._lateness_max_s == self._lateness_max_s:
            out["lateness_ms_max"] = self._lateness_max_s * 1e3
        return out

    def report(
        self, steps: int, scheduling: Scheduling | None, cpus_awake: CpusAwake | None = None
    ) -> dict:
        """Loop timing figures of the first ``steps`` steps (wall time, lateness, late steps):
        the manifest's ``timing``.

        Parameters
        ----------
        steps : int
            The steps made (those the figures cover).
        scheduling : Scheduling or None
            How the hub's threads were scheduled (None: not reported).
        cpus_awake : CpusAwake, optional
            Whether idle CPUs were held awake (None: not reported).
        """
        n, wall, running = steps, self.wall_s(), self.running_s()
        out = {
            "mode": self.mode,
            "period_ms": self.period_ms,
            "steps": n,
            "wall_s": wall,
            "paused_s": self.paused_total_s(),
            "steps_per_s": n / running if running > 0 else 0.0,
            "x_realtime": n * self.period_ms / 1e3 / running if running > 0 else 0.0,
            # the loop's thread's time not waiting, and in lockstep the replies' threads'
            "hub_busy_s": max(wall - self.waiting_s, 0.0) + self.direct_busy_s,
            "hub_cpu_s": self.cpu_s(),
            "late_steps": int(self.late_steps),
            "late_share": self.late_steps / n if n else 0.0,
        }
        if scheduling is not None:
            out["scheduling"] = scheduling.to_dict()
        if cpus_awake is not None:
            out["cpus_awake"] = cpus_awake.to_dict()
        cpus = available_cpus()
        if cpus is not None:
            out["cpus"] = sorted(cpus)  # those the hub's process could run on
        if n:
            step_ms = self.step_wall_s[:n] * 1e3
            out["step_ms_median"] = float(np.median(step_ms))
            out["step_ms_p99"] = float(np.percentile(step_ms, 99))
        if n:
            out["round_trip_ms"] = self.round_trip_ms(n)
        if n and self.mode == "realtime":
            late_ms = self.lateness_s[:n] * 1e3
            out["lateness_ms_median"] = float(np.nanmedian(late_ms))
            out["lateness_ms_p99"] = float(np.nanpercentile(late_ms, 99))
            out["lateness_ms_max"] = float(np.nanmax(late_ms))
        return out


def counts(online, late: Counter, missed: dict[str, set[int]], dropped: dict[str, Counter]) -> dict:
    """The manifest's ``counts``: online bursts, late, missing and dropped messages by role.

    Parameters
    ----------
    online : OnlineTally or None
        The hub's :class:`~hub.burst_observer.OnlineTally`; None when ``[online]`` is off.
    late : Counter
        Role → replies that came after the policy stood in for them.
    missed : dict
        Role → the steps whose reply was missing.
    dropped : dict
        Role → Counter of dropped messages by kind.
    """
    if online is not None:
        found = online.counts()
    else:
        found = {"single_channel_bursts_online": 0, "network_bursts_online": 0}
        found["online_analysis"] = "off"
    return {
        **found,
        "late": dict(late),
        "missing": {r: len(s) for r, s in missed.items() if s},
        "dropped": {r: dict(c) for r, c in dropped.items()},
    }


def steps_share(desc: Description, final: dict[str, dict]) -> dict:
    """An endpoint's final counters, its CPU time made that of the steps alone (the
    counters it described itself with at the start taken off).

    Parameters
    ----------
    desc : Description
        What the endpoint described at the start (its role, its ``counters``).
    final : dict
        Role → that endpoint's counters at the end.
    """
    out = dict(final.get(desc.role, {}))
    start = (desc.counters or {}).get("cpu_s")
    if isinstance(out.get("cpu_s"), float) and isinstance(start, float):
        out["cpu_s"] = out["cpu_s"] - start
    return out
