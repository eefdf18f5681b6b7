"""The burst observer detects bursts beside the loop and reports them to the hub, which
records them; the loop never waits for it and goes on without it."""

import contextlib
import json
import queue
import signal
import threading
import time

import pytest

from hub import wire
from hub.burst_observer import NAME, REPORT_GAP_S, BurstObserver, OnlineTally
from hub.bus import open_session, payload_bytes
from hub.config import load_config
from hub.launch import start_burst_observer
from hub.protocol import (
    BurstReport,
    HubStatus,
    ObservedSpikes,
    ObserverEnd,
    ObserverStart,
    RunReply,
    SpikeBatch,
    StepWindow,
)
from hub.shelf import Shelf
from tests.harness import harness, subscribed, wait_for
from tests.hub.test_live_bursts import CHANNELS, PLANTED, _batches
from tests.windows import RUN


@pytest.fixture
def observed(bus_overrides):
    """A router (the hub's side) and a burst observer on its own session and thread."""
    bus = load_config(None, bus_overrides).bus
    hub = open_session(bus, listener=True)
    observer_session = open_session(bus, listener=False)
    stop = threading.Event()
    observer = BurstObserver(observer_session, bus.keys)
    thread = threading.Thread(target=observer.serve, args=(stop,), daemon=True)
    thread.start()
    # its token is declared after its queryable: seen by the router, the queryable is too
    # (queried at once, the router once did not know of it yet: no reply, no refusal)
    alive = bus.keys.alive("observer", NAME)
    wait_for(lambda: any(r.ok is not None for r in hub.liveliness().get(alive, timeout=1.0)), 10)
    yield hub, bus.keys
    stop.set()
    thread.join(5)
    observer_session.close()
    hub.close()


def _start(hub, keys, key, **params):
    start = ObserverStart(run=RUN, n_steps=60, channel=CHANNELS, key=key, **params)
    (raw,) = wire.get(hub, keys.observer_run(NAME), start.encode(), timeout_s=5)
    return RunReply.decode(raw)


def _forwarder(hub, keys, key):
    """Leaves SpikeBatches for the observer to ask for, as the hub does: kept on a shelf,
    answered sealed with ``key``."""
    shelf = Shelf(key=key)
    queryable = shelf.declare(hub, keys.observer_spikes(NAME))

    def forward(*batches):
        shelf.put(ObservedSpikes(run=RUN, batches=[b.encode() for b in batches]).encode())

    forward.queryable = queryable  # declared while the forwarder is kept
    return forward


def _stranger(hub, keys, batch):
    """Answers the observer's next question for spikes with ``batch``, not sealed with the
    run's key (a participant that is not the hub)."""
    prefix, answered = keys.observer_spikes(NAME), []

    def answer(query):
        if not answered:
            raw = ObservedSpikes(run=RUN, batches=[batch.encode()]).encode()
            wire.reply(query, raw, key_expr=f"{prefix}/0badcafe-1", key=b"x" * 16)
            answered.append(query)
        query.drop()

    return hub.declare_queryable(f"{prefix}/*", answer), answered


def test_it_reports_a_network_burst_under_way_then_complete_and_a_final_count(observed):
    hub, keys = observed
    key = wire.new_key()
    reports: queue.SimpleQueue = queue.SimpleQueue()
    inbox = wire.Inbox(key)
    declared = [  # noqa: F841
        hub.declare_subscriber(
            keys.observer_reports(NAME),
            lambda s: reports.put(inbox.feed(s.payload, s.attachment)),
        )
    ]
    assert _start(hub, keys, key).ok
    forward = _forwarder(hub, keys, key)
    batches = list(_batches(PLANTED, 60))

    def next_report(timeout_s=10.0):
        return BurstReport.decode(reports.get(timeout=timeout_s))

    # Up to 130 ms, a step at a time: three channels are bursting (from 100, 102 and
    # 104 ms), none has ended.
    for batch in batches[:13]:
        forward(batch)
    report = next_report()
    while report.onset_ms is None:
        report = next_report()
    assert report.onset_ms == pytest.approx(102.0) and report.network_bursts == 0
    stranger, answered = _stranger(hub, keys, batches[12])  # a copy of a step
    wait_for(lambda: answered, 10)
    stranger.undeclare()
    forward(*batches[13:30])  # many steps at once, as in lockstep
    forward(*batches[30:])
    report = next_report()
    while not report.network_bursts:
        report = next_report()
    assert report.network_burst_rows() == [(100.0, 119.0, 3, 102.0, 117.0)]

    (raw,) = wire.get(
        hub, keys.observer_run(NAME), ObserverEnd(run=RUN, steps=60).encode(), timeout_s=10
    )
    final = BurstReport.decode(raw)
    assert final.final and final.missing_steps == 0
    assert (final.bursts, final.network_bursts, final.dropped) == (3, 1, 1)
    assert final.network_burst_rows() == report.network_burst_rows()


def test_it_refuses_a_run_whose_detector_parameters_are_wrong_and_says_which(observed):
    hub, keys = observed
    reply = _start(hub, keys, wire.new_key(), network={"min_fraction": 2.0})
    assert not reply.ok and "min_fraction" in reply.reason


def test_steps_whose_spikes_never_come_are_counted_missing(observed, monkeypatch):
    monkeypatch.setattr("hub.burst_observer.END_WAIT_S", 0.2)
    hub, keys = observed
    key = wire.new_key()
    assert _start(hub, keys, key).ok
    forward = _forwarder(hub, keys, key)
    batches = list(_batches(PLANTED, 20))
    forward(*batches[:5])
    forward(*batches[8:])  # steps 5-7 lost on the way
    (raw,) = wire.get(
        hub, keys.observer_run(NAME), ObserverEnd(run=RUN, steps=60).encode(), timeout_s=10
    )
    final = BurstReport.decode(raw)
    assert final.final and final.missing_steps == 3 + 40 and final.network_bursts == 1


def test_reports_without_news_go_at_most_every_quarter_second_of_wall_time(observed):
    """A lockstep run covers many seconds of run time a second: the counts' report (every
    second of run time) must not wake the hub for each."""
    hub, keys = observed
    key = wire.new_key()
    reports: queue.SimpleQueue = queue.SimpleQueue()
    declared = [  # noqa: F841
        hub.declare_subscriber(keys.observer_reports(NAME), lambda s: reports.put(time.monotonic()))
    ]
    assert _start(hub, keys, key).ok
    forward = _forwarder(hub, keys, key)
    silent = [SpikeBatch(**StepWindow.of(RUN, k, 1.0).stamp) for k in range(60)]  # 1 s steps
    started = time.monotonic()
    for batch in silent:  # a minute of run time, each second its own message
        forward(batch)
    (raw,) = wire.get(
        hub, keys.observer_run(NAME), ObserverEnd(run=RUN, steps=60).encode(), timeout_s=10
    )
    elapsed_s = time.monotonic() - started
    assert BurstReport.decode(raw).missing_steps == 0  # every second of it was analysed
    # Every report was put before the final answer, but each comes through its own
    # subscriber's thread: the first may still be on its way here.
    times = [reports.get(timeout=5)]
    with contextlib.suppress(queue.Empty):
        while True:
            times.append(reports.get(timeout=0.5))
    assert len(times) <= 1 + elapsed_s / REPORT_GAP_S, (len(times), elapsed_s)


def _manifest(run_dir):
    return json.loads((run_dir / "manifest.json").read_text())


def test_a_run_records_the_observers_reports_and_counts(tmp_path, bus_overrides):
    with harness(tmp_path, bus_overrides, "online.enabled=true", "experiment.duration_s=2") as h:
        result = h.run()  # the hub starts the observer (online.launch = "local")
    assert result.outcome == "completed"
    assert "observing run" in (h.run_dir / "observer.log").read_text()
    counts = _manifest(h.run_dir)["counts"]
    assert counts["online_analysis"] == "complete"
    # The test culture fires on one channel only: bursts, never a network burst.
    assert counts["single_channel_bursts_online"] > 0 and counts["network_bursts_online"] == 0
    taken = [e.payload["role"] for e in h.record.events if e.key == "run_taken"]
    assert sorted(taken) == ["body", "culture", "observer"]


def test_the_loop_goes_on_when_the_observer_dies_and_the_manifest_says_so(
    tmp_path, bus_overrides, monkeypatch
):
    overrides = ["online.enabled=true", 'loop.mode="realtime"', "experiment.duration_s=3"]
    with harness(tmp_path, bus_overrides, *overrides) as h:

        def kill(observer, statuses):
            observer.popen.send_signal(signal.SIGKILL)

        result = _run_doing_to_the_observer(h, monkeypatch, kill)
    assert result.outcome == "completed" and result.steps == 300
    counts = _manifest(h.run_dir)["counts"]
    assert counts["online_analysis"].startswith("incomplete: the burst observer vanished")
    dead = [e.payload for e in h.record.events if e.key == "dead"]
    assert dead == [{"role": "observer", "id": NAME}]


def _run_doing_to_the_observer(h, monkeypatch, act):
    """Run ``h``, doing ``act(observer, statuses)`` to the burst observer the hub starts (a
    :class:`~hub.launch.LocalProcess`) once the hub's status says the run made 50 steps
    (``statuses``: the hub's statuses so far, as published on ``hub/status``)."""
    started, statuses = [], []

    def start(*args):  # the hub's own start of its observer, kept for ``act``
        started.append(start_burst_observer(*args))
        return started[-1]

    monkeypatch.setattr("hub.online.start_burst_observer", start)

    def act_when_running():
        wait_for(lambda: any(s.step > 50 for s in statuses), timeout_s=60)
        act(started[0], statuses)

    actor = threading.Thread(target=act_when_running, daemon=True)
    actor.start()
    keys = h.cfg.bus.keys
    with subscribed(h.cfg.bus, keys.hub_status, lambda s: statuses.append(_status(s))):
        result = h.run()
    actor.join(35)
    return result


def _status(sample) -> HubStatus:
    return HubStatus.decode(payload_bytes(sample))


def _run_freezing_the_observer(h, monkeypatch):
    """Run ``h``, freezing the burst observer (``SIGSTOP``) until the hub's status says it
    is gone from the bus (its lease lapsed), then letting it go on."""

    def freeze_until_vanished(observer, statuses):
        observer.popen.send_signal(signal.SIGSTOP)
        seen = len(statuses)
        try:
            wait_for(
                lambda: any(f"observer/{NAME}" not in s.alive for s in statuses[seen:]),
                timeout_s=30,
            )
        finally:
            observer.popen.send_signal(signal.SIGCONT)

    return _run_doing_to_the_observer(h, monkeypatch, freeze_until_vanished)


def test_an_observer_frozen_past_its_lease_catches_up_on_its_return(
    tmp_path, bus_overrides, monkeypatch
):
    overrides = ["online.enabled=true", 'loop.mode="realtime"', "experiment.duration_s=8"]
    with harness(tmp_path, bus_overrides, *overrides) as h:
        result = _run_freezing_the_observer(h, monkeypatch)
    assert result.outcome == "completed" and result.steps == 800
    manifest = _manifest(h.run_dir)
    # the spikes of the freeze were kept for it: its analysis has every step
    assert manifest["counts"]["online_analysis"] == "complete"
    assert manifest["counts"]["online_steps_missing"] == 0
    [rejoin] = manifest["rejoins"]
    # back within the step it went in, at times: a return takes no whole step
    assert rejoin["role"] == "observer" and rejoin["at_step"] >= rejoin["gone_at_step"]
    events = [(e.key, e.payload["role"]) for e in h.record.events if e.key in ("dead", "rejoined")]
    assert events == [("dead", "observer"), ("rejoined", "observer")]


def test_an_observer_frozen_as_the_run_ends_is_asked_again_and_its_final_report_counts(
    tmp_path, bus_overrides, monkeypatch
):
    """Its lease lapsing as the hub asked for the final report, the question ended
    unanswered and the run's analysis read "did not answer at the run's end", though the
    observer, running again, was back within milliseconds with its run (a CI flake)."""

    def freeze_over_the_end(observer, statuses):
        wait_for(lambda: any(s.step >= 770 for s in statuses), timeout_s=60)
        observer.popen.send_signal(signal.SIGSTOP)
        try:
            time.sleep(1.6)  # the freeze under test: past the run's end and a 1 s lease
        finally:
            observer.popen.send_signal(signal.SIGCONT)

    overrides = ["online.enabled=true", 'loop.mode="realtime"', "experiment.duration_s=8"]
    with harness(tmp_path, bus_overrides, *overrides) as h:
        result = _run_doing_to_the_observer(h, monkeypatch, freeze_over_the_end)
    assert result.outcome == "completed"
    counts = _manifest(h.run_dir)["counts"]
    assert counts["online_analysis"] in ("complete", "incomplete"), counts  # it answered


def test_an_observer_back_after_the_spikes_kept_for_it_counts_the_steps_it_missed(
    tmp_path, bus_overrides, monkeypatch
):
    monkeypatch.setattr("hub.online.OBSERVER_KEEP_S", 0.1)  # less than any lease
    overrides = ["online.enabled=true", 'loop.mode="realtime"', "experiment.duration_s=8"]
    with harness(tmp_path, bus_overrides, *overrides) as h:
        result = _run_freezing_the_observer(h, monkeypatch)
    assert result.outcome == "completed"
    counts = _manifest(h.run_dir)["counts"]
    assert counts["online_analysis"] == "incomplete"
    assert counts["online_steps_missing"] > 0


def test_an_external_observer_that_never_comes_is_named_with_how_to_start_it(
    tmp_path, bus_overrides
):
    overrides = ["online.enabled=true", 'online.launch="external"', "loop.wait_timeout_s=2"]
    with harness(tmp_path, bus_overrides, *overrides) as h:
        result = h.run()
    assert result.outcome == "fault"
    assert "observer/bursts did not appear" in result.reason
    assert "neuvision observe bursts CONFIG --connect HOST" in result.reason


def test_the_hub_keeps_each_network_burst_seen_under_way_with_when_it_was_last_seen():
    tally = OnlineTally()

    def report(until_ms, onset_ms=None):
        tally.take(BurstReport(run=RUN, until_ms=until_ms, bursts=0, network_bursts=0,
                               onset_ms=onset_ms))  # fmt: skip

    report(120.0, 102.0)
    report(130.0, 102.5)  # the same burst, its onset refined as channels join
    report(150.0)  # over by 150 ms
    report(900.0, 880.0)  # another
    assert [list(u) for u in tally.under_way] == [[102.0, 150.0], [880.0, 900.0]]
    assert tally.onset_ms == 880.0
