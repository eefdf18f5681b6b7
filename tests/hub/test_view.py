"""What the hub gathers for live displays (hub/view.py) and the HubView message."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from hub import wire
from hub.protocol import (
    HubView,
    MotorCommand,
    ProtocolError,
    SensorReading,
    SpikeBatch,
    Stimulation,
)
from hub.shelf import Asker, Shelf
from hub.view import ObserverView
from tests.windows import RUN, W


def _spikes(k, channel, t_ms):
    return SpikeBatch(**W(k).stamp, channel=channel, t_ms=t_ms)


def _reading(k, x):
    return SensorReading(
        step=k, run=RUN, t_s=(k + 1) * 0.01, ranges_m=[0.1, 0.25], pose=[x, -x, 1.0], contact=False
    )


def _stim(k, channel):
    n = len(channel)
    return Stimulation(
        **W(k).stamp,
        channel=channel,
        amplitude_ua=np.full(n, 5.0),
        width_ms=np.full(n, 0.2),
        onset_ms=np.full(n, 1.0),
    )


def test_nothing_is_gathered_while_nobody_watches():
    view = ObserverView(RUN)
    view.took(_spikes(0, [1], [2.0]))
    view.took(_reading(0, 0.1))
    assert view.build(1) is None


def test_a_view_holds_every_spike_pulse_and_position_since_the_last_and_the_newest_reading():
    view = ObserverView(RUN)
    view.watch(True)
    for k in range(3):
        view.took(_spikes(k, [k, 7], [1.0, 2.5]))
        view.took(_reading(k, 0.1 * k))
        view.sent(_stim(k + 1, [4, 5]))
        view.sent(MotorCommand(**W(k + 1).stamp, left_mps=0.01 * k, right_mps=0.02))
    view.sent(Stimulation.none(W(4)))  # no pulse: nothing to show
    v = HubView.decode(view.build(3).encode())
    assert v.step == 3 and v.run == RUN
    assert (v.from_s, v.to_s) == pytest.approx((0.0, 0.03))
    assert v.spike_channel.tolist() == [0, 7, 1, 7, 2, 7]
    assert v.spike_t_ms.tolist() == pytest.approx([1.0, 2.5, 11.0, 12.5, 21.0, 22.5])
    assert v.pulse_channel.tolist() == [4, 5, 4, 5, 4, 5]
    assert v.pulse_t_ms.tolist() == pytest.approx([11.0, 11.0, 21.0, 21.0, 31.0, 31.0])
    assert v.trail_m.tolist() == pytest.approx([0, 0, 0.1, -0.1, 0.2, -0.2])
    assert v.sensors_step == 2 and v.pose.tolist() == pytest.approx([0.2, -0.2, 1.0])
    assert v.ranges_m.tolist() == pytest.approx([0.1, 0.25]) and v.contact is False
    assert (v.left_mps, v.right_mps) == pytest.approx((0.02, 0.02))
    # the next view starts where this one ended
    assert view.build(3) is None
    view.took(_spikes(3, [], []))
    nxt = view.build(4)
    assert nxt.spike_channel.size == 0 and (nxt.from_s, nxt.to_s) == pytest.approx((0.03, 0.04))
    assert nxt.sensors_step == 2  # still the newest reading


def test_a_late_reading_does_not_replace_a_newer_one():
    view = ObserverView(RUN)
    view.watch(True)
    view.took(_reading(5, 0.5))
    view.took(_reading(4, 0.4))
    assert view.build(6).sensors_step == 5


def test_a_view_is_checked_like_any_message():
    with pytest.raises(ProtocolError) as exc:
        HubView(step=1, run=RUN, from_s=0.2, to_s=0.1)
    assert exc.value.kind == "inconsistent"
    with pytest.raises(ProtocolError):
        HubView(step=1, run=RUN, from_s=0.0, to_s=0.1, trail_m=[0.1, 0.2, 0.3])
    with pytest.raises(ProtocolError):
        HubView(step=1, run=RUN, from_s=0.0, to_s=0.1, spike_channel=[1], spike_t_ms=[])


def test_a_view_keeps_the_newest_spikes_up_to_its_bound(monkeypatch):
    import hub.view

    monkeypatch.setattr(hub.view, "MAX_VIEW_SPIKES", 5)
    view = ObserverView(RUN)
    view.watch(True)
    for k in range(4):
        view.took(_spikes(k, [k, k], [1.0, 2.0]))
    v = view.build(4)
    assert v.spike_channel.tolist() == [2, 2, 3, 3]
    assert (v.from_s, v.to_s) == pytest.approx((0.02, 0.04))  # the observer sees a gap before


# ---------------------------------------------------------------- handed over when asked


def test_the_shelf_answers_the_views_after_the_one_named_and_all_it_keeps_to_a_stranger():
    shelf = Shelf(keep=3)
    for k in range(1, 6):
        shelf.put(b"view %d" % k)
    e = shelf.epoch  # each name: <epoch>-<number>-<the number it follows in the answer>
    assert shelf.after(f"{e}-3") == [(f"{e}-4-3", b"view 4"), (f"{e}-5-4", b"view 5")]
    assert shelf.after(f"{e}-5") == []
    assert shelf.after(f"{e}-3-2") == shelf.after(f"{e}-3")  # a whole name sent back
    kept = [(f"{e}-3-0", b"view 3"), (f"{e}-4-3", b"view 4"), (f"{e}-5-4", b"view 5")]
    assert shelf.after("") == kept  # a first question: the oldest kept (two went)
    # one that fell behind: a gap, said (3 follows 1: 2 is no longer kept), not a stall
    assert shelf.after(f"{e}-1") == [(f"{e}-3-1", b"view 3"), *kept[1:]]
    assert shelf.after("0badcafe-4") == kept  # a mark of another hub's
    assert shelf.after("", max_bytes=7) == kept[:1]  # an answer's bytes are capped, at
    assert shelf.after("", max_bytes=14) == kept[:2]  # least one view in each


def test_the_hub_gathers_while_someone_asked_within_the_last_second():
    shelf = Shelf()
    assert not shelf.watched()
    shelf.after("")
    assert shelf.watched(within_s=1.0)
    shelf.asked_at -= 1.5
    assert not shelf.watched(within_s=1.0)


def test_the_hub_waits_for_a_watcher_to_have_its_last_view_but_not_forever():
    shelf = Shelf()
    shelf.put(b"last")
    assert not shelf.wait_had(0.05)
    threading.Timer(0.05, shelf.after, [f"{shelf.epoch}-1"]).start()
    assert shelf.wait_had(5.0)


@pytest.mark.bus
def test_an_asker_gets_each_view_once_in_order_and_asks_only_when_answered(bus_overrides):
    """A real Zenoh exchange: views over one put's size come framed and whole; a second
    question goes only once the first is answered, so a watcher that stops asking is sent
    nothing more."""
    from hub.bus import open_session
    from hub.config import load_config

    cfg = load_config(None, bus_overrides)
    hub = open_session(cfg.bus, listener=True)
    try:
        shelf = Shelf()
        key = cfg.bus.keys.hub_view
        queryable = shelf.declare(hub, key)  # noqa: F841 (kept: declared while it lives)
        watcher = open_session(cfg.bus, listener=False)
        asker = Asker(watcher, key)
        big = bytes(range(256)) * 600  # 150 kB: four frames
        got: list[bytes] = []
        for view in (b"one", big, b"three"):
            shelf.put(view)
            deadline = time.monotonic() + 10
            while len(got) < shelf.seq and time.monotonic() < deadline:
                got += asker.take()
                time.sleep(0.01)
        assert got == [b"one", big, b"three"] and asker.dropped == {}
        asked = asker.asked
        shelf.put(b"four")  # not asked for: nothing comes
        time.sleep(0.3)
        assert asker.asked == asked and asker._got == []
        watcher.close()
    finally:
        hub.close()


@pytest.mark.bus
def test_an_asker_leaves_what_follows_a_reply_lost_on_the_way_for_its_next_question(
    bus_overrides,
):
    """A reply dropped on a congested link (here: left out of the first answer on purpose)
    leaves a hole the asker sees; it takes what came before it and asks again from
    there, so what it takes has no hole."""
    from hub.bus import open_session
    from hub.config import load_config

    cfg = load_config(None, bus_overrides)
    hub = open_session(cfg.bus, listener=True)
    try:
        shelf = Shelf()
        key = cfg.bus.keys.hub_view
        answers = []

        def answer(query):  # as Shelf.answer, but the first answer loses its second reply
            replies = shelf.after(str(query.parameters.get("after") or ""))
            answers.append(len(replies))
            for i, (name, raw) in enumerate(replies):
                if not (len(answers) == 1 and i == 1):
                    wire.reply(query, raw, key_expr=f"{key}/{name}", final=False)
            query.drop()

        queryable = hub.declare_queryable(f"{key}/*", answer)  # noqa: F841 (kept)
        for k in range(1, 5):
            shelf.put(b"view %d" % k)
        watcher = open_session(cfg.bus, listener=False)
        asker = Asker(watcher, key)
        got: list[bytes] = []
        deadline = time.monotonic() + 10
        while len(got) < 4 and time.monotonic() < deadline:
            got += asker.take()
            time.sleep(0.01)
        assert got == [b"view 1", b"view 2", b"view 3", b"view 4"]
        assert answers[:2] == [4, 3]  # asked again after view 1
        assert asker.dropped == {"gap": 2}  # views 3 and 4 of the first answer
        watcher.close()
    finally:
        hub.close()
