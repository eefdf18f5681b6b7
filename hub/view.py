"""What the hub gathers for its observers between two views (:class:`HubView`), and how
they are handed over (``hub/view/*``, asked for).

A live display (the dashboard) could subscribe to the loop's own keys, but then the hub's
router would send it every loop message as it routes it, four a step, with the loop's
congestion control (BLOCK): in a lockstep closed loop that cost the loop 8-30 % of its
speed on two cores (docs/dashboard.md), and an observer on a slow link would hold the
loop up. Instead the hub keeps, while anyone asks for views, the replies it accepts and
the inputs it sends, and builds them into one view ``loop.view_hz`` times a second.

The views are not published: an observer *asks* for them (:class:`ViewAsker`), one
question at a time, for those after the last one it has, and the hub answers from the
views it keeps (:class:`ViewShelf`). Published, the views went on whether or not the
observer took them; an observer that stopped reading (frozen, or on a link slower than
the views) filled its socket, and from then on Zenoh held the hub's put — *drop* or not,
queued transport or not — until the observer read again: the loop stood still
(docs/dashboard.md, "A frozen dashboard"). Asked for, at most one answer is on its way to
each observer.

Plain data: the hub calls :meth:`ObserverView.took` and :meth:`ObserverView.sent` under its
lock, and :meth:`ObserverView.build` from its loop's thread; the shelf is shared with
Zenoh's thread that answers the questions, under its own lock.
"""

from __future__ import annotations

import math
import secrets
import threading
import time
from collections import Counter, deque

import numpy as np

from hub import wire
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


# Views the hub keeps for observers that ask (2 s at 30 views a second): one that asks later
# than that has a gap, never a false silence.
SHELF_VIEWS = 64
# An answer holds the views asked for up to this many bytes (at least one view); the rest go
# in the next: what is on its way to an observer stays within any socket's buffer.
ANSWER_MAX_BYTES = 512_000
# The hub gathers views while someone asked for one this recently.
WATCHED_S = 1.0
# How long an observer waits for the hub's answer before it asks again.
ASK_TIMEOUT_S = 2.0


class ViewShelf:
    """The hub's latest views, numbered from 1 within the shelf's ``epoch`` (random: a
    number of another hub's, or of this one's before it started again, is not taken for
    one of this shelf's), for the observers that ask for them."""

    def __init__(self, keep: int = SHELF_VIEWS):
        self._lock = threading.Condition()
        self._views: deque[tuple[int, bytes]] = deque(maxlen=keep)
        self.epoch = secrets.token_hex(4)
        self.seq = 0  # the newest view's number
        self._had = 0  # the newest view's number some observer said it had
        self.asked_at = -math.inf  # time.monotonic() of the last question

    def put(self, raw: bytes) -> None:
        """Keep a new view (the oldest kept goes, past ``keep``)."""
        with self._lock:
            self.seq += 1
            self._views.append((self.seq, raw))

    def after(self, mark: str, max_bytes: int = ANSWER_MAX_BYTES) -> list[tuple[str, bytes]]:
        """The views kept after the one named ``mark`` (``<epoch>-<number>``; from the
        oldest kept if it is not one of this shelf's), oldest first, each with its name, up
        to ``max_bytes`` (at least one); and note the question."""
        epoch, _, seq = mark.partition("-")
        with self._lock:
            self.asked_at = time.monotonic()
            after = int(seq) if epoch == self.epoch and seq.isdigit() else 0
            if after > self._had:
                self._had = after
                self._lock.notify_all()
            out, size = [], 0
            for n, raw in self._views:
                if n > after:
                    size += len(raw)
                    if out and size > max_bytes:
                        break
                    out.append((f"{self.epoch}-{n}", raw))
            return out

    def wait_had(self, timeout_s: float) -> bool:
        """Wait until an observer has had the newest view (it asked for those after it), at
        most ``timeout_s``: the run's last view, before the hub leaves the bus."""
        with self._lock:
            return self._lock.wait_for(lambda: self._had >= self.seq, timeout_s)

    def watched(self, within_s: float = WATCHED_S) -> bool:
        """Whether anyone asked within the last ``within_s``."""
        return time.monotonic() - self.asked_at < within_s

    def answer(self, query, key_prefix: str) -> None:
        """Answer a question ``<key_prefix>/*?after=MARK``: each view after the one named
        ``MARK`` on ``<key_prefix>/<its name>``, framed if large, then the end."""
        try:
            for name, raw in self.after(str(query.parameters.get("after") or "")):
                wire.reply(query, raw, key_expr=f"{key_prefix}/{name}", final=False)
        finally:
            query.drop()


class ViewAsker:
    """An observer's side of ``hub/view/*``: :meth:`take` returns the whole views that came
    since the last call (as bytes, oldest first) and, when the last question is answered,
    asks the next one — for the views after the newest it has. One question at a time, so
    an observer that stops taking stops the hub's sending too.

    Replies are handled in Zenoh's own thread; the query asks that they be dropped
    rather than waited for on a congested link.
    """

    def __init__(self, session, key_prefix: str, *, timeout_s: float = ASK_TIMEOUT_S):
        self.session = session
        self.key_prefix = key_prefix
        self.timeout_s = timeout_s
        self.mark = ""  # the newest view's name taken (<epoch>-<number>)
        self.asked = 0  # questions asked
        self.dropped: Counter[str] = Counter()  # replies that did not reassemble, by kind
        self._lock = threading.Lock()
        self._got: list[bytes] = []
        self._answered = threading.Event()
        self._answered.set()

    def take(self) -> list[bytes]:
        """The whole views that came since the last call; asks again if answered."""
        with self._lock:
            got, self._got = self._got, []
        if self._answered.is_set():
            self._ask()
        return got

    def _ask(self) -> None:
        import zenoh  # here: the rest of this module is plain data, free of the bus

        self._answered.clear()
        inboxes: dict[str, wire.Inbox] = {}

        def on_reply(reply) -> None:
            sample = reply.ok
            if sample is None:
                return
            key = str(sample.key_expr)
            try:
                raw = inboxes.setdefault(key, wire.Inbox()).feed(sample.payload, sample.attachment)
            except wire.WireError as exc:
                self.dropped[exc.kind] += 1
                return
            if raw is not None:  # an answer's views come in order
                with self._lock:
                    self._got.append(raw)
                    self.mark = key.rsplit("/", 1)[1]

        self.asked += 1
        # indirect=False: the replies are handled in Zenoh's own thread (on_reply only
        # reassembles and appends); the default starts a Python thread for each question,
        # which was a fifth of a dashboard's CPU at 30 questions a second
        self.session.get(
            f"{self.key_prefix}/*?after={self.mark}",
            zenoh.handlers.Callback(on_reply, self._answered.set, indirect=False),
            consolidation=zenoh.ConsolidationMode.NONE,
            congestion_control=zenoh.CongestionControl.DROP,
            timeout=self.timeout_s,
        )
