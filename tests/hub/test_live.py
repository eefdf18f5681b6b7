"""The hub detects bursts and network bursts on the live spike stream, step by step."""

import threading

import numpy as np
import pytest

from hub.analysis.bursts import BurstParams
from hub.analysis.network_bursts import NetworkBurstParams
from hub.bus import open_session
from hub.config import ConfigError, load_config
from hub.live import BackgroundLiveBursts, LiveBursts
from hub.loop import Hub
from hub.protocol import Description, SpikeBatch
from tests.endpoints import EchoBody, EchoCulture
from tests.windows import RUN

PERIOD_MS = 10.0
# Channel ids need not be 0..n-1: a real MEA names its electrodes.
CULTURE = Description(
    role="culture", id="0", kind="x", channel=[12, 13, 21, 87], x_um=[0] * 4, y_um=[0] * 4
)


def _batches(spikes_by_channel, n_steps):
    """Split planted spike times (absolute ms) into one SpikeBatch per step."""
    channel = np.concatenate([np.full(len(t), c) for c, t in spikes_by_channel.items()])
    t_ms = np.concatenate([np.asarray(t, float) for t in spikes_by_channel.values()])
    order = np.argsort(t_ms, kind="stable")
    channel, t_ms = channel[order], t_ms[order]
    for k in range(n_steps):
        t0 = k * PERIOD_MS
        inside = (t_ms >= t0) & (t_ms < t0 + PERIOD_MS)
        yield SpikeBatch(
            step=k,
            run=RUN,
            t0_s=t0 / 1e3,
            t1_s=(t0 + PERIOD_MS) / 1e3,
            channel=channel[inside],
            t_ms=t_ms[inside] - t0,
        )


# Channels 12, 13, 21 of 4 each fire 4 spikes 5 ms apart near 100 ms: one network burst.
PLANTED = {c: [100 + 2 * i + 5 * j for j in range(4)] for i, c in enumerate((12, 13, 21))}
PLANTED[87] = [30.0, 400.0]  # lone spikes elsewhere


@pytest.mark.parametrize("every_ms", [0.0, 100.0])
@pytest.mark.parametrize("deadline", [None, 1e12])  # no limit; a deadline never reached
def test_a_planted_network_burst_is_found_once_however_it_is_fed(every_ms, deadline, monkeypatch):
    monkeypatch.setattr("hub.live.CHUNK_SPIKES", 2)
    live = LiveBursts(CULTURE, BurstParams(), NetworkBurstParams(), every_ms)
    found = []
    for batch in _batches(PLANTED, 60):
        live.add(batch)
        if live.due:
            found += live.work(deadline)
    found += live.work()  # the end of the run feeds the rest
    assert live.bursts == 3 and live.network_bursts == 1
    (nb,) = found
    assert nb.start_ms == pytest.approx(100.0) and nb.end_ms == pytest.approx(119.0)
    assert sorted(nb.channels) == [0, 1, 2]  # detector indices of channels 12, 13, 21


def test_a_feed_that_breaks_off_for_the_caller_keeps_the_rest_and_drops_nothing(monkeypatch):
    monkeypatch.setattr("hub.live.CHUNK_SPIKES", 2)
    live = LiveBursts(CULTURE, BurstParams(), NetworkBurstParams(), 0.0)
    calls = iter(range(10**6))
    found, behind_ms = [], []
    for batch in _batches(PLANTED, 60):
        live.add(batch)
        assert live.work(pause=lambda: True) == []  # something else to do at once: no feed
        found += live.work(pause=lambda: next(calls) % 3 == 2)  # two chunks, then a break
        behind_ms.append(live.backlog_ms)
    assert max(behind_ms) > PERIOD_MS  # it fell behind during the planted burst
    found += live.work()
    assert live.backlog_ms == 0 and live.skipped_spikes == 0
    assert live.bursts == 3 and live.network_bursts == 1
    (nb,) = found
    assert nb.start_ms == pytest.approx(100.0) and nb.end_ms == pytest.approx(119.0)


def test_on_a_thread_of_its_own_the_detector_finds_the_same_network_burst():
    background = BackgroundLiveBursts(LiveBursts(CULTURE, BurstParams(), NetworkBurstParams(), 100))
    for batch in _batches(PLANTED, 60):
        background.add(batch)
    (nb,) = background.completed() + background.close()
    assert nb.start_ms == pytest.approx(100.0) and nb.end_ms == pytest.approx(119.0)
    assert background.live.bursts == 3 and background.live.network_bursts == 1


def test_a_hub_that_has_no_time_for_live_analysis_drops_old_spikes_and_says_so(monkeypatch):
    monkeypatch.setattr("hub.live.MAX_BACKLOG_MS", 50.0)
    live = LiveBursts(CULTURE, BurstParams(), NetworkBurstParams(), 0.0)
    for batch in _batches(PLANTED, 41):  # up to 410 ms
        live.add(batch)
        live.work(deadline=0.0)  # always too late to start a chunk
    n_planted = sum(len(t) for t in PLANTED.values())
    assert live.skipped_spikes == n_planted - 1  # all but the spike at 400 ms, < 50 ms old
    assert live.network_bursts == 0


def _hub(*overrides):
    hub = Hub(load_config(None, list(overrides)))
    hub.prepare({"body": EchoBody().describe(), "culture": EchoCulture().describe()})
    return hub


def test_the_hub_reports_live_bursts_in_its_status():
    hub = _hub()
    # The test culture's channels are 0..3.
    renamed = {new: PLANTED[old] for new, old in enumerate(PLANTED)}
    for batch in _batches(renamed, 60):
        hub.scheduler.hand_over(batch)  # as the lockstep hub hands each step's spikes over
    hub.scheduler.work_live(flush=True)
    assert hub.status().extra["network_bursts"] == 1
    assert hub.counts()["single_channel_bursts_online"] == 3


def test_live_analysis_can_be_switched_off_and_its_parameters_are_checked():
    assert _hub("online.enabled=false").live is None
    with pytest.raises(ConfigError, match="online.network"):
        _hub("online.network.min_fraction=2.0")


def test_on_a_thread_of_its_own_work_left_past_its_time_is_done_at_close():
    live = LiveBursts(CULTURE, BurstParams(), NetworkBurstParams(), 0.0)
    background = BackgroundLiveBursts(live)
    for batch in _batches(PLANTED, 60):
        background.add(batch, until=0.0)  # the next step has always begun already
    (nb,) = background.completed() + background.close()
    assert nb.start_ms == pytest.approx(100.0) and nb.end_ms == pytest.approx(119.0)
    assert live.bursts == 3 and live.skipped_spikes == 0  # 600 ms behind at most: kept


def test_a_lockstep_hub_with_analysis_due_still_handles_the_event_that_waits(bus_overrides):
    hub = _hub(*bus_overrides)
    session = open_session(hub.cfg.bus, listener=True)
    try:
        hub.attach(session)
        renamed = {new: PLANTED[old] for new, old in enumerate(PLANTED)}
        for batch in _batches(renamed, 60):  # 600 ms of spikes: analysis is due
            hub.scheduler.hand_over(batch)
        hub.request_stop("test")  # ... and an event waits
        steps = threading.Thread(target=hub.scheduler.run, daemon=True)
        steps.start()
        steps.join(10)
        assert not steps.is_alive(), "the loop never handled the stop"
        assert hub.stop_reason == "test"
        assert hub.live.network_bursts == 1  # analysed in full at the end all the same
    finally:
        session.close()
