"""Sealing and framing of payloads on the bus (wire contract v2, items 4 and 5; docs/wire.md).

Every loop message is *sealed*: a 16-byte keyed BLAKE2b tag made with the run key of the
endpoint it goes to or comes from, so a receiver takes a payload only from who holds that
key. Every payload of any size *passes*: Zenoh's low-latency transport (``bus.low_latency``,
the default) cannot carry a message larger than one batch (in practice about 49 kB; see
FRAME_MAX_BYTES), so a payload larger than :data:`FRAME_MAX_BYTES` is split into frames put
one after another on the same key and reassembled by the receiver.

Each put carries a fixed-layout, little-endian header (:data:`HEADER`)::

    magic  b"NW"      2 bytes
    version           1 byte  (TRAILER_VERSION sealed, ATTACHMENT_VERSION open)
    message id        uint32  (per Outbox, incremented per message)
    frame index       uint32  (0 .. count-1)
    frame count       uint32  (1 for a payload that fits one put)

A *sealed* put is ``frame ‖ tag ‖ header``: the seal ends the payload, and the put has no
Zenoh attachment (an attachment on every message of the loop cost the trivial lockstep loop
5.5 % in an ablation, docs/wire.md). An *open* put (no key: views, query replies) is the
frame as it is, a plain msgpack map when it fits one put, with the header as its Zenoh
attachment.

The tag of a single-frame message is ``blake2b(payload, key=key, digest_size=16)``. The
tag of each frame of a split message covers that frame's header *and* its bytes, so a frame
injected or spliced by anyone without the key is refused on its own (``foreign``) and never
disturbs the genuine message being reassembled; the frames' tags together authenticate the
whole payload.

A receiver (:class:`Inbox`, one per key it subscribes to: frames of one key arrive in
order from one publisher) returns the whole payload once complete; it raises
:class:`WireError` ``"foreign"`` when it has a key and the put is not sealed with it, and
``"frame"`` for malformed framing (bad header, a frame out of order or of another message,
a message over ``max_message_bytes``). A message abandoned incomplete because another
started is counted in :attr:`Inbox.abandoned`. Memory held is at most one message's frames
of at most ``max_message_bytes``.

Queries: :func:`reply` answers a query with framed replies, :func:`get` reassembles them.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import struct

KEY_BYTES = 16
TAG_BYTES = 16
# Payload bytes per put. Zenoh's low-latency batch is 65,535 bytes, but measured here
# (eclipse-zenoh 1.10, router + clients on loopback) a put whose payload is over about
# 49,050 bytes (with a 31-byte attachment, any key length) never arrives, while the link
# stays up: 48,000 leaves room for the attachment and Zenoh's headers.
FRAME_MAX_BYTES = 48_000
# Largest message an Inbox reassembles (a 100k-neuron culture's burst is a few MB).
MAX_MESSAGE_BYTES = 256 << 20

MAGIC = b"NW"
ATTACHMENT_VERSION = 1  # the header in an open message's attachment
TRAILER_VERSION = 2  # the header at the end of a sealed message's payload, after its tag
HEADER = struct.Struct("<2sBIII")  # magic, version, message id, frame index, frame count
_HEADER_BYTES = HEADER.size
SEAL_BYTES = TAG_BYTES + _HEADER_BYTES  # what a sealed put adds after its frame
_ID_MASK = 0xFFFFFFFF
_blake2b = hashlib.blake2b
_compare = hmac.compare_digest
_pack = HEADER.pack
_unpack_from = HEADER.unpack_from


def new_key() -> bytes:
    """A fresh random run key of :data:`KEY_BYTES` bytes."""
    return secrets.token_bytes(KEY_BYTES)


def tag(payload: bytes, key: bytes) -> bytes:
    """The 16-byte keyed BLAKE2b tag of ``payload`` under ``key``.

    Parameters
    ----------
    payload : bytes
        What the tag covers.
    key : bytes
        The run key (at most 64 bytes; :data:`KEY_BYTES` in the project).
    """
    return _blake2b(payload, key=key, digest_size=TAG_BYTES).digest()


def _keyed(key: bytes | None):
    """BLAKE2b keyed with ``key``, to be copied for each tag (keying it anew for each costs
    a third of a small message's tag), or None."""
    return None if key is None else _blake2b(key=key, digest_size=TAG_BYTES)


def _frame_tag(header: bytes, frame: bytes | memoryview, key: bytes) -> bytes:
    h = _blake2b(header, key=key, digest_size=TAG_BYTES)
    h.update(frame)
    return h.digest()


class WireError(ValueError):
    """A payload refused on the wire.

    Attributes
    ----------
    kind : str
        ``"foreign"`` (missing or bad tag: not from the holder of the key) or
        ``"frame"`` (malformed or out-of-order framing, or a message too large).

    Parameters
    ----------
    kind : str
        As the attribute.
    message : str
        What was wrong.
    """

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind


def frames(
    payload: bytes, key: bytes | None, message_id: int, frame_max_bytes: int = FRAME_MAX_BYTES
) -> list[tuple[bytes | memoryview, bytes | None]]:
    """The ``(put payload, attachment)`` pairs that carry ``payload`` (one when it fits):
    sealed, each frame followed by its tag and header, with no attachment; open, each frame
    as it is, with its header as the attachment.

    Parameters
    ----------
    payload : bytes
        The whole message.
    key : bytes or None
        The run key that seals it; None: open.
    message_id : int
        The message's id in the headers (taken modulo 2**32).
    frame_max_bytes : int
        Largest payload of one frame.
    """
    n = len(payload)
    message_id &= _ID_MASK
    count = max(-(-n // frame_max_bytes), 1)
    view = memoryview(payload) if count > 1 else payload
    out = []
    for index in range(count):
        chunk = view[index * frame_max_bytes : (index + 1) * frame_max_bytes] if count > 1 else view
        if key is None:
            out.append((chunk, _pack(MAGIC, ATTACHMENT_VERSION, message_id, index, count)))
            continue
        header = _pack(MAGIC, TRAILER_VERSION, message_id, index, count)
        if count == 1:
            tag = _blake2b(chunk, key=key, digest_size=TAG_BYTES).digest()
        else:
            tag = _frame_tag(header, chunk, key)
        out.append((b"".join((chunk, tag, header)), None))
    return out


class Outbox:
    """Sends payloads through one Zenoh publisher: sealed when it has a key, framed when large.

    Parameters
    ----------
    publisher : zenoh.Publisher
        Where the frames go (declared with the loop's publish settings).
    key : bytes or None
        The run key that seals every message; ``None``: unsealed (frames still apply).
    frame_max_bytes : int
        Largest payload of one put.
    """

    def __init__(self, publisher, key: bytes | None = None, *, frame_max_bytes=FRAME_MAX_BYTES):
        if frame_max_bytes < 1:
            raise ValueError("frame_max_bytes must be >= 1")
        self.publisher = publisher
        self.key = key  # and its keyed hash
        self.frame_max_bytes = frame_max_bytes
        self._put = publisher.put
        self._next_id = secrets.randbits(32)

    @property
    def key(self) -> bytes | None:
        """The run key that seals every message (None: unsealed)."""
        return self._key

    @key.setter
    def key(self, key: bytes | None) -> None:
        self._key, self._mac = key, _keyed(key)

    def put(self, payload: bytes) -> None:
        """Put ``payload`` (sealed if a key is set; in frames if over ``frame_max_bytes``)."""
        message_id = self._next_id
        self._next_id = (message_id + 1) & _ID_MASK
        if len(payload) <= self.frame_max_bytes:  # the common, small-message path
            mac = self._mac
            if mac is None:
                self._put(payload, attachment=_pack(MAGIC, ATTACHMENT_VERSION, message_id, 0, 1))
                return
            mac = mac.copy()
            mac.update(payload)
            header = _pack(MAGIC, TRAILER_VERSION, message_id, 0, 1)
            self._put(b"".join((payload, mac.digest(), header)))
            return
        for chunk, attachment in frames(payload, self._key, message_id, self.frame_max_bytes):
            if attachment is None:
                self._put(chunk)
            else:
                self._put(bytes(chunk), attachment=attachment)


def _as_bytes(data) -> bytes | None:
    if data is None or isinstance(data, bytes):
        return data
    if isinstance(data, (bytearray, memoryview)):
        return bytes(data)
    return data.to_bytes()  # zenoh.ZBytes


class Inbox:
    """Takes the frames received on one key and gives back whole, authentic payloads.

    Parameters
    ----------
    key : bytes or None
        The run key the sender seals with; ``None``: tags are not required (frames are
        still reassembled, and a put with no attachment is taken as a whole payload).
    max_message_bytes : int
        Largest payload reassembled; a larger one is refused (``"frame"``) and its
        frames freed.

    Attributes
    ----------
    abandoned : int
        Messages dropped incomplete because the next one started (each a lost message,
        to be counted as ``frame`` by the caller along with the :class:`WireError` raised).

    Not thread-safe: feed one Inbox from one thread at a time (its key's subscriber
    callback, or the thread that drains what that callback queued).
    """

    def __init__(self, key: bytes | None = None, *, max_message_bytes=MAX_MESSAGE_BYTES):
        self._key, self._mac = key, _keyed(key)
        self.max_message_bytes = max_message_bytes
        self.abandoned = 0
        self._id = -1  # message being reassembled (-1: none)
        self._count = 0
        self._parts: list[bytes] = []
        self._size = 0
        self._skip_id = -1  # a refused message whose remaining frames are dropped quietly

    @property
    def key(self) -> bytes | None:
        """The run key; setting it (a new run) also drops a message being reassembled."""
        return self._key

    @key.setter
    def key(self, key: bytes | None) -> None:
        self._key, self._mac = key, _keyed(key)
        self._reset()
        self._skip_id = -1

    @property
    def pending_bytes(self) -> int:
        """Bytes held for the message being reassembled."""
        return self._size

    def _reset(self) -> None:
        self._id = -1
        self._parts = []
        self._size = 0

    def _refuse(self, message: str, message_id: int = -1) -> WireError:
        self._reset()
        self._skip_id = message_id
        return WireError("frame", message)

    def _unseal(self, data: bytes) -> tuple[bytes, int, int, int]:
        """A sealed put's frame, message id, frame index and count, once its tag is right."""
        n = len(data)
        if n < SEAL_BYTES:
            raise WireError("foreign", f"a put of {n} bytes: not sealed")
        magic, version, message_id, index, count = _unpack_from(data, n - _HEADER_BYTES)
        if magic != MAGIC or version != TRAILER_VERSION:
            raise WireError("foreign", "no sealed trailer (magic or version): not sealed")
        end = n - SEAL_BYTES
        frame = data[:end]
        if count == 1 and index == 0:
            mac = self._mac.copy()
            mac.update(frame)
            expected = mac.digest()
        else:
            expected = _frame_tag(data[n - _HEADER_BYTES :], frame, self._key)
        if not _compare(data[end : n - _HEADER_BYTES], expected):
            raise WireError("foreign", "bad tag")
        return frame, message_id, index, count

    def feed(self, payload, attachment=None) -> bytes | None:
        """Take one received put; return the whole payload once complete, else ``None``.

        Parameters
        ----------
        payload : bytes (or zenoh.ZBytes)
            The put's payload (sealed: its frame, tag and header).
        attachment : bytes, zenoh.ZBytes or None
            The put's attachment: an open put's header (not read when a key is set).

        Raises
        ------
        WireError
            ``"foreign"``: not sealed with the key (only when a key is set);
            ``"frame"``: malformed or out-of-order framing, or a message too large.
        """
        payload = _as_bytes(payload)
        if self._key is not None:
            payload, message_id, index, count = self._unseal(payload)
        else:
            attachment = _as_bytes(attachment)
            if attachment is None:
                if len(payload) > self.max_message_bytes:
                    raise WireError("frame", f"message of {len(payload)} bytes over the limit")
                return payload
            n_att = len(attachment)
            if n_att not in (_HEADER_BYTES, SEAL_BYTES):
                raise WireError("frame", f"attachment of {n_att} bytes")
            magic, version, message_id, index, count = _unpack_from(attachment)
            if magic != MAGIC or version != ATTACHMENT_VERSION:
                raise WireError("frame", "not a framed attachment (magic or version)")
        if count == 1 and index == 0:  # the common, single-frame path
            if self._id != -1:
                self.abandoned += 1
                self._reset()
            if len(payload) > self.max_message_bytes:
                raise WireError("frame", f"message of {len(payload)} bytes over the limit")
            return payload
        if index >= count:
            raise self._refuse(f"frame {index} of {count}")
        if index == 0:
            if self._id != -1:
                self.abandoned += 1
                self._reset()
            # All frames but the last are as large as the first: the total is known now.
            if (count - 1) * len(payload) + 1 > self.max_message_bytes or not payload:
                raise self._refuse(
                    f"message of {count} frames of {len(payload)} bytes over the limit",
                    message_id,
                )
            self._id, self._count = message_id, count
            self._parts, self._size = [payload], len(payload)
            self._skip_id = -1
            return None
        if message_id != self._id:
            if message_id == self._skip_id:
                return None  # the rest of a message refused already (counted once)
            raise self._refuse(f"frame {index} of message {message_id} without its start")
        if count != self._count or index != len(self._parts):
            raise self._refuse(f"frame {index} of {count} out of order", message_id)
        self._size += len(payload)
        if self._size > self.max_message_bytes:
            raise self._refuse(f"message over {self.max_message_bytes} bytes", message_id)
        self._parts.append(payload)
        if index + 1 < count:
            return None
        whole = b"".join(self._parts)
        self._reset()
        return whole


def reply(
    query,
    payload: bytes,
    *,
    key_expr: str | None = None,
    final: bool = True,
    key: bytes | None = None,
) -> None:
    """Answer ``query`` with ``payload``, in several framed replies if it is large.

    The query is dropped explicitly: Zenoh sends a query's final answer when the object is
    freed, and a reference kept elsewhere (a logged exception's traceback reaches the
    callback's frame) would leave the asker waiting for its whole timeout.

    Parameters
    ----------
    query : zenoh.Query
        The query answered.
    payload : bytes
        The whole answer.
    key_expr : str, optional
        The key the replies go on (default: the query's).
    final : bool
        Finish the query after this answer; False: more answers to come.
    key : bytes, optional
        The run key that seals the replies; None: open.
    """
    key_expr = key_expr or query.key_expr
    for chunk, attachment in frames(payload, key, secrets.randbits(32)):
        query.reply(key_expr, bytes(chunk), attachment=attachment)
    if final:
        query.drop()


def get(session, key: str, payload: bytes | None = None, *, timeout_s: float) -> list[bytes]:
    """Query ``key`` and return the whole payload of each reply (framed replies reassembled).

    Replies in error and malformed frame sequences are left out. Replies of several
    queryables are kept apart by replier and key, in the order they completed. Replies
    are taken open (no run key).

    Parameters
    ----------
    session : zenoh.Session
        An open session.
    key : str
        The key expression queried (parameters may follow a ``?``).
    payload : bytes, optional
        The query's payload.
    timeout_s : float
        How long to wait for replies.
    """
    import zenoh

    inboxes: dict[tuple, Inbox] = {}
    out = []
    replies = session.get(
        key,
        payload=payload,
        timeout=timeout_s,
        # Every framed reply shares its key: the default consolidation would keep one.
        consolidation=zenoh.ConsolidationMode.NONE,
    )
    for r in replies:
        sample = r.ok
        if sample is None:
            continue
        who = (str(r.replier_id), str(sample.key_expr))
        inbox = inboxes.setdefault(who, Inbox())
        try:
            whole = inbox.feed(sample.payload, sample.attachment)
        except WireError:
            continue
        if whole is not None:
            out.append(whole)
    return out
