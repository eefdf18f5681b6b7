"""Sealing and framing (hub/wire.py): any size passes, only the key holder's payloads count."""

from __future__ import annotations

import hashlib
import queue
import secrets

import numpy as np
import pytest
import zenoh

from hub.bus import LOOP_PUBLISH, free_tcp_port, open_session
from hub.config import BusSection
from hub.wire import (
    FRAME_MAX_BYTES,
    HEADER,
    KEY_BYTES,
    TAG_BYTES,
    TRAILER_VERSION,
    Inbox,
    Outbox,
    WireError,
    frames,
    get,
    new_key,
    reply,
    tag,
)
from tests.harness import wait_for


class FakePublisher:
    """Collects what an Outbox puts, as a subscriber would receive it."""

    def __init__(self):
        self.puts: list[tuple[bytes, bytes | None]] = []

    def put(self, payload, *, attachment=None):
        self.puts.append((bytes(payload), attachment))


def _sent(payload, key=None, **kw):
    pub = FakePublisher()
    Outbox(pub, key, **kw).put(payload)
    return pub.puts


def _deliver(inbox, puts):
    """Feed every put; return the whole payloads that came out."""
    return [w for w in (inbox.feed(p, a) for p, a in puts) if w is not None]


def test_keys_are_random_and_tags_are_keyed_blake2b():
    a, b = new_key(), new_key()
    assert len(a) == KEY_BYTES and a != b
    assert tag(b"x", a) == hashlib.blake2b(b"x", key=a, digest_size=16).digest()
    assert tag(b"x", a) != tag(b"x", b)


def test_a_sealed_small_payload_is_one_put_of_the_payload_its_tag_and_its_header():
    key = new_key()
    puts = _sent(b"hello", key)
    assert len(puts) == 1 and puts[0][1] is None  # no attachment: the seal is in the payload
    put = puts[0][0]
    header = put[-HEADER.size :]
    assert put == b"hello" + tag(b"hello", key) + header
    assert HEADER.unpack(header)[1:2] + HEADER.unpack(header)[3:] == (TRAILER_VERSION, 0, 1)
    assert _deliver(Inbox(key), puts) == [b"hello"]


def test_an_open_payload_is_one_put_as_it_is_with_its_header_as_attachment():
    puts = _sent(b"hello")
    assert len(puts) == 1 and puts[0][0] == b"hello" and len(puts[0][1]) == HEADER.size
    assert _deliver(Inbox(), puts) == [b"hello"]


@pytest.mark.parametrize("size", [0, 1, FRAME_MAX_BYTES, FRAME_MAX_BYTES + 1, 1 << 20])
@pytest.mark.parametrize("sealed", [True, False])
def test_any_size_arrives_whole_and_no_put_is_larger_than_a_frame(size, sealed):
    key = new_key() if sealed else None
    payload = bytes(range(256)) * (size // 256) + bytes(size % 256)
    puts = _sent(payload, key)
    seal = TAG_BYTES + HEADER.size if sealed else 0
    assert all(len(p) <= FRAME_MAX_BYTES + seal for p, _ in puts)
    assert len(puts) == max(1, -(-size // FRAME_MAX_BYTES))
    inbox = Inbox(key)
    assert _deliver(inbox, puts) == [payload]
    assert inbox.pending_bytes == 0


def test_messages_follow_one_another_on_one_inbox():
    key = new_key()
    pub = FakePublisher()
    out = Outbox(pub, key, frame_max_bytes=10)
    payloads = [b"a" * 25, b"b", b"c" * 10, b"d" * 11]
    for p in payloads:
        out.put(p)
    assert _deliver(Inbox(key), pub.puts) == payloads


def test_a_new_run_key_is_set_on_both_sides():
    pub = FakePublisher()
    out, inbox = Outbox(pub, new_key()), Inbox()
    out.key = inbox.key = new_key()
    out.put(b"step")
    assert _deliver(inbox, pub.puts) == [b"step"]


def test_a_new_run_key_drops_a_message_half_reassembled_under_the_old_one():
    old, new = new_key(), new_key()
    inbox = Inbox(old)
    assert inbox.feed(*_sent(bytes(30), old, frame_max_bytes=10)[0]) is None
    inbox.key = new
    assert inbox.pending_bytes == 0
    assert _deliver(inbox, _sent(bytes(30), new, frame_max_bytes=10)) == [bytes(30)]


@pytest.mark.parametrize("size", [10, FRAME_MAX_BYTES * 3])
def test_a_payload_sealed_with_another_key_or_not_at_all_is_foreign(size):
    key = new_key()
    for puts in (_sent(bytes(size), new_key()), _sent(bytes(size), None)):
        inbox = Inbox(key)
        with pytest.raises(WireError) as err:
            _deliver(inbox, puts)
        assert err.value.kind == "foreign"
    with pytest.raises(WireError) as err:
        Inbox(key).feed(b"plain", None)  # a plain put, as a v1 sender makes
    assert err.value.kind == "foreign"


def test_a_tampered_payload_or_frame_is_foreign():
    key = new_key()
    ((put, _),) = _sent(b"left=0.1", key)
    with pytest.raises(WireError, match="bad tag"):
        Inbox(key).feed(b"left=9.9" + put[8:])
    puts = _sent(bytes(30), key, frame_max_bytes=10)
    puts[1] = (b"x" * 10 + puts[1][0][10:], None)
    inbox = Inbox(key)
    assert inbox.feed(*puts[0]) is None
    with pytest.raises(WireError) as err:
        inbox.feed(*puts[1])
    assert err.value.kind == "foreign"


def test_a_strangers_frames_do_not_disturb_the_genuine_message_being_reassembled():
    key = new_key()
    genuine = _sent(b"g" * 30, key, frame_max_bytes=10)
    stranger = _sent(b"s" * 30, new_key(), frame_max_bytes=10)
    inbox = Inbox(key)
    got = []
    for mine, theirs in zip(genuine, stranger, strict=True):
        with pytest.raises(WireError):
            inbox.feed(*theirs)
        got.append(inbox.feed(*mine))
    assert got == [None, None, b"g" * 30] and inbox.abandoned == 0


def test_without_a_key_open_frames_are_reassembled_and_a_plain_put_is_a_whole_payload():
    assert Inbox().feed(b"plain", None) == b"plain"
    assert _deliver(Inbox(), _sent(b"x" * 25, None, frame_max_bytes=10)) == [b"x" * 25]


def test_a_missing_frame_drops_the_message_as_frame_and_the_next_one_arrives():
    puts = _sent(b"a" * 30, None, frame_max_bytes=10) + _sent(b"b" * 30, None, frame_max_bytes=10)
    del puts[1]  # frame 1 of the first message lost
    inbox = Inbox()
    assert inbox.feed(*puts[0]) is None
    with pytest.raises(WireError) as err:
        inbox.feed(*puts[1])
    assert err.value.kind == "frame" and inbox.pending_bytes == 0
    assert _deliver(inbox, puts[2:]) == [b"b" * 30]


def test_a_message_started_while_another_is_incomplete_abandons_it_and_counts_it():
    first = _sent(b"a" * 30, None, frame_max_bytes=10)
    second = _sent(b"b" * 30, None, frame_max_bytes=10)
    inbox = Inbox()
    assert _deliver(inbox, first[:2] + second) == [b"b" * 30]
    assert inbox.abandoned == 1
    assert _deliver(inbox, first[:1] + _sent(b"small", None)) == [b"small"]
    assert inbox.abandoned == 2


def test_a_message_over_the_limit_is_refused_at_its_first_frame_and_holds_no_memory():
    puts = _sent(bytes(100), None, frame_max_bytes=10)
    inbox = Inbox(max_message_bytes=50)
    with pytest.raises(WireError) as err:
        inbox.feed(*puts[0])
    assert err.value.kind == "frame"
    # The rest of that message is dropped quietly (counted once), and the next one passes.
    assert _deliver(inbox, puts[1:]) == [] and inbox.pending_bytes == 0
    assert _deliver(inbox, _sent(bytes(40), None, frame_max_bytes=10)) == [bytes(40)]


def test_a_message_that_grows_past_the_limit_is_refused_and_freed():
    # A sender that lies about its frame size: small first frame, large later ones.
    pairs = frames(bytes(30), None, 7, frame_max_bytes=10)
    inbox = Inbox(max_message_bytes=25)
    assert inbox.feed(bytes(10), pairs[0][1]) is None
    with pytest.raises(WireError) as err:
        inbox.feed(bytes(20), pairs[1][1])
    assert err.value.kind == "frame" and inbox.pending_bytes == 0
    assert inbox.feed(bytes(10), pairs[2][1]) is None  # the rest of it: dropped quietly


@pytest.mark.parametrize(
    "attachment",
    [b"", b"NW", b"XX" + bytes(13), b"NW\x09" + bytes(12), bytes(40), b"NW\x01" + bytes(12)],
)
def test_a_malformed_attachment_is_frame(attachment):
    # The last one: frame index 0 of 0 frames.
    with pytest.raises(WireError) as err:
        Inbox().feed(b"payload", attachment)
    assert err.value.kind == "frame"


def test_frames_of_an_unknown_message_are_frame():
    puts = _sent(bytes(30), None, frame_max_bytes=10)
    with pytest.raises(WireError) as err:
        Inbox().feed(*puts[2])
    assert err.value.kind == "frame"


def test_zenoh_bytes_are_accepted_as_payload_and_attachment():
    key = new_key()
    ((sealed, _),) = _sent(b"z", key)
    assert Inbox(key).feed(zenoh.ZBytes(sealed)) == b"z"
    ((payload, att),) = _sent(b"z")
    assert Inbox().feed(zenoh.ZBytes(payload), zenoh.ZBytes(att)) == b"z"


# --------------------------------------------------------------------- over real Zenoh


@pytest.fixture
def bus():
    """A router session (as the hub's) and two client sessions (as endpoints'), loopback,
    low-latency transport as configured by default."""
    section = BusSection(
        session=f"test-{secrets.token_hex(4)}",
        listen=(f"tcp/127.0.0.1:{free_tcp_port()}",),
        scouting=False,
    )
    assert section.low_latency  # the default this test is about
    router = open_session(section, listener=True)
    clients = []
    try:
        clients = [open_session(section, listener=False) for _ in range(2)]
        yield section, router, clients
    finally:
        for s in clients + [router]:
            s.close()


def _subscribe(session, key):
    inbox: queue.SimpleQueue = queue.SimpleQueue()
    sub = session.declare_subscriber(key, lambda s: inbox.put((s.payload, s.attachment)))
    return sub, inbox


def _wait_matching(publisher, timeout_s=10.0):
    wait_for(lambda: publisher.matching_status.matching, timeout_s)


def test_1_mb_and_20_mb_payloads_pass_the_low_latency_transport_framed(bus):
    section, router, (a, b) = bus
    key_expr = f"{section.keys.root}/culture/0/spikes"
    sub, received = _subscribe(b, key_expr)
    publisher = a.declare_publisher(key_expr, **LOOP_PUBLISH)
    _wait_matching(publisher)
    key = new_key()
    out, inbox = Outbox(publisher, key), Inbox(key)
    rng = np.random.default_rng(0)
    for size in (1 << 20, 20 << 20):
        payload = rng.bytes(size)
        out.put(payload)
        whole = None
        while whole is None:
            whole = inbox.feed(*received.get(timeout=20))
        assert whole == payload
    # The link is still up: a small message follows.
    out.put(b"after")
    assert inbox.feed(*received.get(timeout=5)) == b"after"
    del sub


def test_a_large_query_reply_comes_back_whole_in_framed_replies(bus):
    section, router, (a, b) = bus
    key_expr = f"{section.keys.root}/culture/0/describe"
    description = np.random.default_rng(1).bytes(100_000)
    asked = []

    def on_query(query):
        asked.append(None if query.payload is None else query.payload.to_bytes())
        reply(query, description)

    queryable = b.declare_queryable(key_expr, on_query)  # noqa: F841
    got = []
    # The queryable is known to the router shortly after it is declared.
    wait_for(lambda: bool(got.extend(get(a, key_expr, b"run?", timeout_s=2.0)) or got))
    assert got == [description] and asked[-1] == b"run?"


def test_without_framing_a_1_mb_put_never_arrives_over_low_latency(bus):
    # Why framing exists: the low-latency transport cannot carry a message larger than
    # one batch. The 1 MB put is lost (and the link with it, for a moment): small puts
    # after it arrive once the link is back, and the large one never comes before them.
    section, router, (a, b) = bus
    key_expr = f"{section.keys.root}/culture/0/spikes"
    sub, received = _subscribe(b, key_expr)
    publisher = a.declare_publisher(key_expr, **LOOP_PUBLISH)
    _wait_matching(publisher)
    publisher.put(bytes(1 << 20))

    def a_marker_arrived():
        publisher.put(b"marker")
        return not received.empty()

    wait_for(a_marker_arrived, timeout_s=20)
    assert received.get()[0].to_bytes() == b"marker"
    del sub
