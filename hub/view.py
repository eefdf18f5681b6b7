"""What the hub gathers for its observers between two views (:class:`HubView`), and how
they are handed over (``hub/view/*``, asked for).

A live display (the dashboard) could subscribe to the loop's own keys, but then the hub's
router would send it every loop message as it routes it, four a step, with the loop's
congestion control (BLOCK): in a lockstep closed loop that cost the loop 8-30 % of its
speed on two cores (docs/dashboard.md), and an observer on a slow link would hold the
loop up. Instead the hub keeps, while anyone asks for views, the replies it accepts and
the inputs it sends, and builds them into one view ``loop.view_hz`` times a second.

The views are not published: an observer *asks* for them, one question at a time, for
those after the last one it has (:class:`hub.shelf.Asker`), and the hub answers from the
views it keeps (:class:`hub.shelf.Shelf`; why: :mod:`hub.shelf`).

Plain data: the hub calls :meth:`ObserverView.took` and :meth:`ObserverView.sent` under its
lock, and :meth:`ObserverView.build` from its loop's thread.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from hub.protocol import HubView, Message, MotorCommand, SensorReading, SpikeBatch, Stimulation

# Held at most between two views (a loop over 30,000 steps/s at 30 views/s lets the oldest go).
MAX_HELD = 1024
# Spikes in one view at most (~2.4 MB): past it only the newest batches go, and the view
# starts later (a gap for the observer, never a false silence).
MAX_VIEW_SPIKES = 200_000


class ObserverView:
    """The loop's messages since the last view, while ``observed``."""

    def __init__(self, run: str):
        self.run = run
        self.observed = False  # someone subscribes to hub/view (checked at each view)
        self._spikes: deque[SpikeBatch] = deque(maxlen=MAX_HELD)
        self._stims: deque[Stimulation] = deque(maxlen=MAX_HELD)
        self._trail: deque[tuple[float, float]] = deque(maxlen=MAX_HELD)
        self._sensors: SensorReading | None = None
        self._motor: MotorCommand | None = None
        self._n_spikes = 0  # in _spikes (more than it holds once it let the oldest go)
        self._fresh = False  # anything since the last view

    def took(self, message: Message) -> None:
        """A reply the hub accepted (the run's data, on time or late)."""
        if not self.observed:
            return
        if isinstance(message, SpikeBatch):
            self._spikes.append(message)
            self._n_spikes += message.channel.size
        else:
            self._trail.append((message.pose[0], message.pose[1]))
            if self._sensors is None or message.step >= self._sensors.step:
                self._sensors = message
        self._fresh = True

    def sent(self, message: Message) -> None:
        """An input the hub sent."""
        if not self.observed:
            return
        if isinstance(message, Stimulation):
            if message.channel.size:
                self._stims.append(message)
        else:
            self._motor = message

    def watch(self, observed: bool) -> None:
        """Whether anyone subscribes now: gather from here on, or nothing."""
        if observed != self.observed:
            self.observed = observed
            self._spikes.clear()
            self._n_spikes = 0
            self._stims.clear()
            self._trail.clear()
            self._fresh = False

    def build(self, steps_done: int) -> HubView | None:
        """The view of what was gathered since the last one (None if nothing new), and a
        fresh start for the next."""
        if not self._fresh:
            return None
        spikes = self._spikes
        spikes = list(spikes) if self._n_spikes <= MAX_VIEW_SPIKES else _newest(spikes)
        stims = list(self._stims)
        self._spikes.clear()
        self._n_spikes = 0
        self._stims.clear()
        fields = {"step": steps_done, "run": self.run}
        if spikes:
            t0_s = [b.t0_s for b in spikes]
            fields["from_s"] = min(t0_s)
            fields["to_s"] = max([b.t1_s for b in spikes])
            fields["spike_channel"] = np.concatenate([b.channel for b in spikes])
            fields["spike_t_ms"] = _run_ms(t0_s, [b.t_ms for b in spikes])
        else:
            t = self._sensors.t_s if self._sensors is not None else 0.0
            fields["from_s"] = fields["to_s"] = t
        if stims:
            fields["pulse_channel"] = np.concatenate([s.channel for s in stims])
            fields["pulse_t_ms"] = _run_ms([s.t0_s for s in stims], [s.onset_ms for s in stims])
        if self._trail:
            fields["trail_m"] = np.array(self._trail, dtype=np.float64).reshape(-1)
            self._trail.clear()
        s = self._sensors
        if s is not None:
            fields.update(sensors_step=s.step, pose=s.pose, ranges_m=s.ranges_m, contact=s.contact)
        if self._motor is not None:
            fields.update(left_mps=self._motor.left_mps, right_mps=self._motor.right_mps)
        self._fresh = False
        return HubView(**fields)


def _run_ms(t0_s: list[float], t_ms: list[np.ndarray]) -> np.ndarray:
    """Times within each message's window (ms after its ``t0_s``) as run times in ms, all
    messages' in one array: a handful of numpy calls a view, not two per message."""
    sizes = [t.size for t in t_ms]
    offsets_ms = np.repeat(np.asarray(t0_s, np.float64) * 1e3, sizes)
    return offsets_ms + np.concatenate(t_ms).astype(np.float64)


def _newest(batches) -> list[SpikeBatch]:
    """The newest batches whose spikes together stay within MAX_VIEW_SPIKES, in order."""
    kept, total = [], 0
    for batch in reversed(batches):
        total += batch.channel.size
        if total > MAX_VIEW_SPIKES and kept:
            break
        kept.append(batch)
    return kept[::-1]
