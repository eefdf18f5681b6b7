"""The replay source: a recorded run played through the same page, at any speed, with a slider.

The run folder is read once with the record's reader (:func:`hub.record.read_run`): the
body's readings and the culture's spikes received (``rx`` and ``late``), the stimulation
and motor commands sent, the descriptions, the network bursts and the late / missing
replies the hub noted, and the manifest's config (the world). :meth:`ReplaySource.tick`
moves the replay's clock on by the wall time since the last tick times the speed and gives
the :class:`~dashboard.state.FrameState` what happened in between, exactly as the live
observer would have; a jump (the slider) empties the state and gives it the history a page
shows at that time. The hub panel shows the replay's position and the counts up to it;
each endpoint's panel its counters at the run's end (the manifest).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from hub.protocol import MotorCommand, SensorReading, Stimulation
from hub.record import DATA_DIRECTIONS, read_run

from .scene import build_scene, world_for
from .state import BURSTS_KEPT_S, RASTER_S, RATE_HISTORY_S, FrameState

SPEEDS = (0.1, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0)
MIN_SPEED, MAX_SPEED = 0.01, 1000.0  # x real time; the page offers SPEEDS and the one given


def _speed_ok(speed: float) -> bool:
    return MIN_SPEED <= speed <= MAX_SPEED  # NaN and infinity fail too


class ReplayError(ValueError):
    """A run folder that cannot be replayed; the message says why."""


class ReplaySource:
    """Plays a recorded run into a `FrameState`, paused until the first page opens.

    Parameters
    ----------
    run_dir : str or Path
        The run folder, read whole on construction.
    state : FrameState
        What the page shows.
    speed : float
        × real time, ``MIN_SPEED`` to ``MAX_SPEED``.

    Raises
    ------
    ReplayError
        The speed is out of range, or the folder holds no body readings to replay.
    """

    def __init__(self, run_dir: str | Path, state: FrameState, speed: float = 1.0):
        if not _speed_ok(speed):
            raise ReplayError(
                f"the speed must be {MIN_SPEED:g} to {MAX_SPEED:g} (x real time), got {speed}"
            )
        self.run_dir = Path(run_dir)
        self.state = state
        self.speed = float(speed)
        rec = read_run(self.run_dir)
        readings = sorted(rec.decoded(SensorReading, *DATA_DIRECTIONS), key=lambda r: r.step)
        if not readings:
            raise ReplayError(f"{self.run_dir} holds no body reading to replay")
        self.manifest = rec.manifest
        config = self.manifest.get("config") or {}
        self.scene = build_scene(rec.descriptions(), config, world_for(config))
        period_ms = self.scene["period_ms"] or 10.0
        # the body: one row per reading, in step order
        self.sensor_t = np.array([r.t_s for r in readings])
        self.sensor_step = np.array([r.step for r in readings])
        self.poses = np.array([r.pose for r in readings]).reshape(-1, 3)
        self.ranges = [r.ranges_m for r in readings]
        self.contact = [r.contact for r in readings]
        # the culture: spikes in time order
        self.spike_channel, self.spike_t_ms = rec.spikes()
        stims = rec.decoded(Stimulation, "tx")
        pulses = [(s.t0_s * 1e3 + s.onset_ms.astype(float), s.channel) for s in stims]
        pulse_t = np.concatenate([p[0] for p in pulses]) if pulses else np.zeros(0)
        pulse_c = np.concatenate([p[1] for p in pulses]) if pulses else np.zeros(0, np.uint32)
        order = np.argsort(pulse_t, kind="stable")
        self.pulse_t_ms, self.pulse_channel = pulse_t[order], pulse_c[order]
        motors = sorted(rec.decoded(MotorCommand, "tx"), key=lambda m: m.step)
        self.motor_t = np.array([m.t0_s for m in motors])
        self.motor = [(m.step, m.left_mps, m.right_mps) for m in motors]
        # what the hub noted: network bursts (shown once ended), late and missing replies
        events = rec.events
        bursts = [
            [b[k] for k in ("start_ms", "end_ms", "n_channels", "core_start_ms", "core_end_ms")]
            for b in rec.network_bursts()
        ]
        # Each is shown once its core has ended, as the live page learns of it: in a closed
        # loop the extent of a stimulated channel's burst may last to the end of the run.
        self.bursts = sorted(sorted(bursts), key=lambda b: b[4])
        self.burst_shown_s = np.array([b[4] / 1e3 for b in self.bursts])
        self.noted: dict[str, list] = {"late": [], "missed": []}  # (run time, role)
        for e in events:
            if e.key in self.noted:
                # a reply is late or missing once its window has passed
                t_s = (e.payload["step"] + 1) * period_ms / 1e3
                self.noted[e.key].append((t_s, e.payload["role"]))
        for noted in self.noted.values():
            noted.sort()
        self.duration_s = float(
            max(self.sensor_t[-1], self.spike_t_ms[-1] / 1e3 if self.spike_t_ms.size else 0.0)
        )
        self.t_s = 0.0  # the replay's clock (run time)
        self.playing = False  # until the first page opens
        self._opened = False
        self._wall = time.monotonic()
        state.source = {"kind": "replay", "run_dir": str(self.run_dir)}

    # ------------------------------------------------------------------ life

    def start(self) -> None:
        """Give the state the run's scene and the replay's time 0."""
        with self.state.lock:
            self.state.set_scene(self.scene)
            self._jump(0.0)
        self._wall = time.monotonic()

    def close(self) -> None:
        """Nothing to release: the run was read whole."""

    def page_opened(self) -> None:
        """A page connected: the first one starts the replay (nobody misses its start)."""
        with self.state.lock:
            if not self._opened:
                self._opened = self.playing = True
                self._wall = time.monotonic()

    # ------------------------------------------------------------------ frames

    def tick(self, now: float | None = None) -> None:
        """Move the clock on to ``now`` (``time.monotonic()``) and feed what happened
        meanwhile (caller holds the lock)."""
        now = time.monotonic() if now is None else now
        elapsed, self._wall = now - self._wall, now
        if self.playing:
            t1 = min(self.t_s + elapsed * self.speed, self.duration_s)
            self._feed(self.t_s, t1)
            self.t_s = t1
            if t1 >= self.duration_s:
                self.playing = False
        self._publish()

    def _feed(self, t0: float, t1: float) -> None:
        """Give the state what happened in run time ``(t0, t1]``."""
        state = self.state
        a, b = np.searchsorted(self.sensor_t, [t0, t1], side="right")
        for i in range(a, b):
            state.add_sensors(
                int(self.sensor_step[i]),
                float(self.sensor_t[i]),
                self.poses[i],
                self.ranges[i],
                self.contact[i],
            )
        m = int(np.searchsorted(self.motor_t, t1, side="right"))
        if m:
            state.add_motor(*self.motor[m - 1])
        a, b = np.searchsorted(self.pulse_t_ms, [t0 * 1e3, t1 * 1e3], side="right")
        if b > a:
            state.add_pulses(self.pulse_channel[a:b], self.pulse_t_ms[a:b])
        self._spikes(t0, t1)
        a, b = np.searchsorted(self.burst_shown_s, [t0, t1], side="right")
        if b > a:
            state.add_bursts(self.bursts[a:b])

    def _jump(self, t_s: float) -> None:
        """Empty the state and give it what a page shows at run time ``t_s``."""
        t_s = min(max(float(t_s), 0.0), self.duration_s)
        state = self.state
        state.reset()
        # The trail from the start, the rest from as far back as the page shows it.
        a = int(np.searchsorted(self.sensor_t, t_s, side="right"))
        for i in range(a):
            state.add_sensors(
                int(self.sensor_step[i]),
                float(self.sensor_t[i]),
                self.poses[i],
                self.ranges[i],
                self.contact[i],
            )
        back = max(t_s - max(RASTER_S, RATE_HISTORY_S), 0.0)
        self._feed_streams(back, t_s)
        self.t_s = t_s

    def _feed_streams(self, t0: float, t1: float) -> None:
        state = self.state
        m = int(np.searchsorted(self.motor_t, t1, side="right"))
        if m:
            state.add_motor(*self.motor[m - 1])
        # (t1 - RASTER_S, t1], as _feed's (t0, t1]: a pulse at the jump's own time is shown
        a, b = np.searchsorted(
            self.pulse_t_ms, [max(t1 - RASTER_S, 0) * 1e3, t1 * 1e3], side="right"
        )
        if b > a:
            state.add_pulses(self.pulse_channel[a:b], self.pulse_t_ms[a:b])
        self._spikes(t0, t1)
        a, b = np.searchsorted(self.burst_shown_s, [max(t1 - BURSTS_KEPT_S, 0), t1], side="right")
        if b > a:
            state.add_bursts(self.bursts[a:b])

    def _spikes(self, t0: float, t1: float) -> None:
        """The spikes of run time ``[t0, t1)`` (s)."""
        a, b = np.searchsorted(self.spike_t_ms, [t0 * 1e3, t1 * 1e3], side="left")
        self.state.add_spikes(self.spike_channel[a:b], self.spike_t_ms[a:b], t0 * 1e3, t1 * 1e3)

    def _publish(self) -> None:
        """The replay's position and the hub's counts up to it, for the page."""
        t = self.t_s
        counts = {}
        for name, noted in self.noted.items():
            per_role: dict[str, int] = {}
            for t_noted, role in noted:
                if t_noted > t:
                    break
                per_role[role] = per_role.get(role, 0) + 1
            counts[name] = per_role
        m = self.manifest
        step = int(self.state.step)
        self.state.set_status(
            {
                "step": max(step, 0),
                "t_s": t,
                "mode": self.scene["mode"],
                "state": "replay" if self.playing else "replay paused",
                "late": counts["late"],
                "missing": counts["missed"],
                "dropped": {
                    r: sum(c.values()) for r, c in m.get("counts", {}).get("dropped", {}).items()
                },
                "alive": [],
                "extra": {
                    "period_ms": self.scene["period_ms"],
                    "n_steps": m.get("steps"),
                    "outcome": m.get("outcome"),
                    "timing": m.get("timing", {}),
                },
            }
        )
        self.state.set_endpoints(
            {
                role: {"id": e.get("id"), "kind": e.get("kind"), "alive": None, "counters": e}
                for role, e in m.get("endpoints", {}).items()
            }
        )
        self.state.replay = {
            "t_s": round(t, 4),
            "duration_s": round(self.duration_s, 4),
            "playing": self.playing,
            "speed": self.speed,
            "speeds": sorted(set(SPEEDS) | {self.speed}),
        }

    # ------------------------------------------------------------------ controls

    def command(self, message: dict) -> dict:
        """``play``, ``pause``, ``seek`` (``t_s``), ``speed`` (``x``) from the page."""
        cmd = message.get("cmd")
        with self.state.lock:
            if cmd == "play":
                if self.t_s >= self.duration_s:
                    self._jump(0.0)
                self.playing = True
                self._wall = time.monotonic()
            elif cmd == "pause":
                self.playing = False
            elif cmd == "seek":
                try:
                    self._jump(float(message.get("t_s")))
                except (TypeError, ValueError):
                    return {"ok": False, "state": "", "reason": "seek needs t_s (seconds)"}
            elif cmd == "speed":
                try:
                    speed = float(message.get("x"))
                except (TypeError, ValueError):
                    speed = 0.0
                if not _speed_ok(speed):
                    reason = f"speed needs x from {MIN_SPEED:g} to {MAX_SPEED:g}"
                    return {"ok": False, "state": "", "reason": reason}
                self.speed = speed
            else:
                return {"ok": False, "state": "", "reason": f"a replay cannot {cmd!r}"}
            self._publish()
            return {"ok": True, "state": self.state.status["state"], "reason": ""}
