"""Messages handed to observers that ask for them, one question at a time.

A publication goes on whether or not its subscriber takes it. A subscriber that stopped
reading (frozen, swapped out, or on a link slower than the messages) fills its socket, and
from then on Zenoh held up the publisher's whole session — *drop* or not, queued transport
or not, from the publishing thread or another — until it read again (where in Zenoh was not
pinned down: every thread of the hub waited, about when the lease lapses). Where the
publisher is the hub, the loop stood still: 0.5-0.7 s in most 1.5 s freezes of a live
display (docs/dashboard.md, "A frozen dashboard") or of the burst observer
(docs/benchmarks.md). So the hub publishes nothing large to an observer: it keeps its
latest messages on a :class:`Shelf` and answers questions ``<prefix>/*?after=MARK`` with
those after the one named; the observer (:class:`Asker`) asks the next question only once
the last is answered, so at most one answer is on its way to it, and one that stops taking
stops the hub's sending too. The hub's live views (:mod:`hub.view`) and the spikes it
forwards to the burst observer (:mod:`hub.burst_observer`) go this way.

Plain data but for :meth:`Shelf.declare` and :meth:`Asker._ask`, which go on the bus.
"""

from __future__ import annotations

import math
import secrets
import threading
import time
from collections import Counter, deque
from collections.abc import Callable

from hub import wire

# Messages kept for observers that ask (2 s of views at 30 a second): one that asks later
# than that has a gap, never a false silence.
SHELF_KEEP = 64
# An answer holds the messages asked for up to this many bytes (at least one); the rest go
# in the next: what is on its way to an observer stays within any socket's buffer.
ANSWER_MAX_BYTES = 512_000
# The hub gathers views while someone asked for one this recently.
WATCHED_S = 1.0
# How long an observer waits for the hub's answer before it asks again.
ASK_TIMEOUT_S = 2.0


class Shelf:
    """The latest messages, numbered from 1 within the shelf's ``epoch`` (random: a
    number of another hub's, or of this one's before it started again, is not taken for
    one of this shelf's), for the observers that ask for them.

    Parameters
    ----------
    keep : int
        Messages kept (the oldest goes past it).
    key : bytes or None
        The run key that seals every answer (:mod:`hub.wire`); None: open.
    """

    def __init__(self, keep: int = SHELF_KEEP, key: bytes | None = None):
        self._lock = threading.Condition()
        self._items: deque[tuple[int, bytes]] = deque(maxlen=keep)
        self.key = key
        self.epoch = secrets.token_hex(4)
        self.seq = 0  # the newest message's number
        self._had = 0  # the newest message's number some observer said it had
        self.asked_at = -math.inf  # time.monotonic() of the last question

    def put(self, raw: bytes) -> None:
        """Keep a new message (the oldest kept goes, past ``keep``)."""
        with self._lock:
            self.seq += 1
            self._items.append((self.seq, raw))

    def after(self, mark: str, max_bytes: int = ANSWER_MAX_BYTES) -> list[tuple[str, bytes]]:
        """The messages kept after the one named ``mark``, oldest first, as ``(name, raw)``
        pairs; and note the question (thread-safe).

        Each comes with its name, ``<epoch>-<number>-<follows>``: ``follows`` is the
        number of the message before it in the answer, or for the first the number asked
        after (0 for a mark not of this shelf's) — a first that does not follow it on
        (``number > follows + 1``) says that the shelf no longer keeps those between. An
        asker that missed a reply on the way (dropped on a congested link) sees the next
        not follow what it has, and asks again (:class:`Asker`).

        Parameters
        ----------
        mark : str
            ``<epoch>-<number>`` (a whole name is taken too); one not of this shelf's
            asks from the oldest kept.
        max_bytes : int
            The answer's messages stop before this many bytes (at least one is given).
        """
        epoch, _, seq = mark.partition("-")
        seq = seq.partition("-")[0]  # an asker that sends a whole name back
        with self._lock:
            self.asked_at = time.monotonic()
            after = int(seq) if epoch == self.epoch and seq.isdigit() else 0
            if after > self._had:
                self._had = after
                self._lock.notify_all()
            out, size, follows = [], 0, after
            for n, raw in self._items:
                if n > after:
                    size += len(raw)
                    if out and size > max_bytes:
                        break
                    out.append((f"{self.epoch}-{n}-{follows}", raw))
                    follows = n
            return out

    def wait_had(self, timeout_s: float) -> bool:
        """Wait until an observer has had the newest message (it asked for those after
        it), at most ``timeout_s``: the run's last, before the hub goes on."""
        with self._lock:
            return self._lock.wait_for(lambda: self._had >= self.seq, timeout_s)

    def watched(self, within_s: float = WATCHED_S) -> bool:
        """Whether anyone asked within the last ``within_s``."""
        return time.monotonic() - self.asked_at < within_s

    def declare(self, session, key_prefix: str):
        """The queryable ``<key_prefix>/*`` on ``session`` that answers from this shelf
        (:meth:`answer`, in Zenoh's thread); keep it as long as the shelf serves.

        Parameters
        ----------
        session : zenoh.Session
            Where it is declared.
        key_prefix : str
            The key expression its questions and answers go under.
        """
        return session.declare_queryable(f"{key_prefix}/*", lambda q: self.answer(q, key_prefix))

    def answer(self, query, key_prefix: str) -> None:
        """Answer a question ``<key_prefix>/*?after=MARK``: each message after the one
        named ``MARK`` on ``<key_prefix>/<its name>``, framed if large (sealed with the
        shelf's key if it has one), then the end (the query is always finished).

        Parameters
        ----------
        query : zenoh.Query
            The question.
        key_prefix : str
            The prefix its answers' keys go under.
        """
        try:
            for name, raw in self.after(str(query.parameters.get("after") or "")):
                wire.reply(query, raw, key_expr=f"{key_prefix}/{name}", final=False, key=self.key)
        finally:
            query.drop()


class Asker:
    """An observer's side of ``<key_prefix>/*``: :meth:`take` returns the whole messages
    that came since the last call (as bytes, oldest first) and, when the last question is
    answered, asks the next one — for the messages after the newest it has. One question
    at a time, so an observer that stops taking stops the hub's sending too.

    Replies are handled in Zenoh's own thread; the query asks that they be dropped
    rather than waited for on a congested link. A message that does not follow the
    newest taken (one before it was dropped so) is left for the next question, counted
    in ``dropped["gap"]``: what is taken has no hole but those the shelf no longer kept.

    Parameters
    ----------
    session : zenoh.Session
    key_prefix : str
    key : bytes or None
        The run key the answers are sealed with (one not sealed with it is dropped,
        counted in ``dropped["foreign"]``); None: open.
    on_answer : callable, optional
        Called (in Zenoh's thread) when a question has been answered in full.
    timeout_s : float
        How long a question waits for its answer before the next may be asked.
    """

    def __init__(
        self,
        session,
        key_prefix: str,
        *,
        key: bytes | None = None,
        on_answer: Callable[[], None] | None = None,
        timeout_s: float = ASK_TIMEOUT_S,
    ):
        self.session = session
        self.key_prefix = key_prefix
        self.key = key
        self.timeout_s = timeout_s
        self.mark = ""  # the newest message's name taken (<epoch>-<number>)
        self.asked = 0  # questions asked
        self.dropped: Counter[str] = Counter()  # replies that did not unseal or reassemble
        self._on_answer = on_answer
        self._lock = threading.Lock()
        self._got: list[bytes] = []
        self._answered = threading.Event()
        self._answered.set()

    def take(self, ask: bool = True) -> list[bytes]:
        """The whole messages that came since the last call; with ``ask``, :meth:`ask`."""
        with self._lock:
            got, self._got = self._got, []
        if ask:
            self.ask()
        return got

    def ask(self) -> bool:
        """Ask for the messages after the newest taken, if the last question has been
        answered (what its answer brought waits for :meth:`take`); whether it asked."""
        if not self._answered.is_set():
            return False
        self._ask()
        return True

    def _ask(self) -> None:
        import zenoh  # here: the rest of this module is plain data, free of the bus

        self._answered.clear()
        inboxes: dict[str, wire.Inbox] = {}

        def on_reply(reply) -> None:
            sample = reply.ok
            if sample is None:
                return
            key = str(sample.key_expr)
            inbox = inboxes.setdefault(key, wire.Inbox(self.key))
            try:
                raw = inbox.feed(sample.payload, sample.attachment)
            except wire.WireError as exc:
                self.dropped[exc.kind] += 1
                return
            if raw is None:  # a frame of a message not whole yet
                return
            epoch, n, follows = _name(key)
            with self._lock:  # an answer's messages come in order
                have_epoch, _, have = self.mark.partition("-")
                if follows is not None and follows != (int(have) if epoch == have_epoch else 0):
                    self.dropped["gap"] += 1
                    return
                self._got.append(raw)
                self.mark = f"{epoch}-{n}"

        def on_end() -> None:
            self._answered.set()
            if self._on_answer is not None:
                self._on_answer()

        self.asked += 1
        # indirect=False: the replies are handled in Zenoh's own thread (on_reply only
        # reassembles and appends); the default starts a Python thread for each question,
        # which was a fifth of a dashboard's CPU at 30 questions a second
        self.session.get(
            f"{self.key_prefix}/*?after={self.mark}",
            zenoh.handlers.Callback(on_reply, on_end, indirect=False),
            consolidation=zenoh.ConsolidationMode.NONE,
            congestion_control=zenoh.CongestionControl.DROP,
            timeout=self.timeout_s,
        )


def _name(key: str) -> tuple[str, int, int | None]:
    """``(epoch, number, follows)`` of a message's key, ``<prefix>/<epoch>-<n>-<follows>``
    (:meth:`Shelf.after`); ``follows`` None for a shelf's before 2026-11-29, whose names
    were ``<epoch>-<n>`` (taken as they come, as then), and -1 for a name that is neither
    (never taken)."""
    parts = key.rsplit("/", 1)[1].split("-")
    if len(parts) in (2, 3) and all(p.isdigit() for p in parts[1:]):
        return parts[0], int(parts[1]), int(parts[2]) if len(parts) == 3 else None
    return parts[0], 0, -1
