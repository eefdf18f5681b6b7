"""The online detector reports, window by window, exactly what the offline detectors find."""

import numpy as np
import pytest

from hub.analysis.bursts import BurstParams, detect_bursts
from hub.analysis.network_bursts import NetworkBurstParams, detect_network_bursts
from hub.analysis.online import Burst, NetworkBurst, OnlineBurstDetector
from hub.analysis.spikes import AnalysisInputError
from tests.analysis.analysis_synth import merge, network_burst, sparse_background


def _random_record(rng, n_channels, t_stop_ms):
    """Poisson background plus a few noisy network bursts, times on a 0.1 ms grid."""
    k = int(rng.integers(0, 30 * n_channels))
    trains = [(rng.integers(0, n_channels, k), rng.uniform(0, t_stop_ms, k))]
    for start in rng.uniform(0, t_stop_ms, 6):
        for c in range(n_channels):
            if rng.random() < 0.6:
                m = int(rng.integers(2, 9))
                trains.append((np.full(m, c), start + rng.uniform(0, 70, m)))
    ch, t = merge(*trains)
    return ch, np.round(t, 1)


def _stream(ch, t, det, window_ms, t_stop_ms):
    events = []
    t_end_ms = max(t_stop_ms, float(t[-1]) if t.size else 0.0)  # noisy bursts may run past
    for w0 in np.arange(0.0, t_end_ms + window_ms, window_ms):
        sel = (t >= w0) & (t < w0 + window_ms)
        events += det.feed(ch[sel], t[sel], until_ms=w0 + window_ms)
    return events + det.flush()


@pytest.mark.parametrize("seed", range(12))
def test_online_equals_offline_on_random_records(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 24))
    t_stop = 4_000.0
    ch, t = _random_record(rng, n, t_stop)
    bp = BurstParams(
        min_spikes=int(rng.integers(2, 5)),
        window_ms=float(rng.choice([10.0, 20.0, 30.0])),
        max_isi_ms=[None, 5.0, 15.0][seed % 3],
    )
    nbp = NetworkBurstParams(
        min_fraction=float(rng.choice([0.1, 0.3, 0.5])),
        merge_gap_ms=float(rng.choice([0.0, 10.0, 30.0])),
    )
    det = OnlineBurstDetector(n, bp, nbp)
    events = _stream(ch, t, det, float(rng.choice([1.0, 10.0, 100.0])), t_stop)

    offline_b = detect_bursts(ch, t, bp)
    offline_nb = detect_network_bursts(offline_b, n, nbp)
    assert np.array_equal(det.bursts, offline_b)
    online_nb = det.network_bursts
    assert online_nb.start_ms.tolist() == offline_nb.start_ms.tolist()
    assert online_nb.end_ms.tolist() == offline_nb.end_ms.tolist()
    assert online_nb.core_start_ms.tolist() == offline_nb.core_start_ms.tolist()
    assert online_nb.core_end_ms.tolist() == offline_nb.core_end_ms.tolist()
    for a, b in zip(online_nb.channels, offline_nb.channels, strict=True):
        assert a.tolist() == b.tolist()
    assert sum(isinstance(e, Burst) for e in events) == offline_b.size
    assert sum(isinstance(e, NetworkBurst) for e in events) == len(offline_nb)


def test_planted_network_burst_is_reported_soon_after_it_ends():
    n = 10
    ch, t = merge(sparse_background(n, 2_000.0, 2.0), network_burst(range(5), 1_000.0, 60.0))
    det = OnlineBurstDetector(n)
    reported_at = {}
    for w0 in np.arange(0.0, 2_000.0, 10.0):
        sel = (t >= w0) & (t < w0 + 10.0)
        for e in det.feed(ch[sel], t[sel], until_ms=w0 + 10.0):
            reported_at.setdefault(type(e).__name__, (w0 + 10.0, e))
    when, nb = reported_at["NetworkBurst"]
    assert (nb.start_ms, nb.end_ms, nb.channels) == (1_000.0, 1_060.0, (0, 1, 2, 3, 4))
    # burst end + window (20) + max ISI (20) + merge gap (10), rounded up to the 10 ms window
    assert 1_060.0 < when <= 1_120.0
    assert det.flush() == []


def test_feed_without_window_end_and_a_burst_cut_by_the_end_of_stream():
    det = OnlineBurstDetector(1)
    assert det.feed([0, 0], [0.0, 1.0]) == []
    assert det.feed([0], [2.0]) == []  # still open: more spikes may join
    events = det.flush()
    assert events == [Burst(0, 0.0, 2.0, 3), NetworkBurst(0.0, 2.0, (0,), 0.0, 2.0)]


def test_empty_stream_and_bad_input():
    det = OnlineBurstDetector(4)
    assert det.advance(1_000.0) == [] and det.flush() == []
    assert det.bursts.size == 0 and len(det.network_bursts) == 0
    det = OnlineBurstDetector(4)
    det.feed([1], [5.0], until_ms=10.0)
    with pytest.raises(AnalysisInputError, match="previous window end"):
        det.feed([1], [9.0])
    with pytest.raises(AnalysisInputError, match="n_channels"):
        det.feed([4], [20.0])
    with pytest.raises(AnalysisInputError, match="n_channels"):
        OnlineBurstDetector(0)


@pytest.mark.parametrize("seed", range(4))
def test_spikes_added_in_pieces_then_advanced_once_give_the_events_of_window_feeds(seed):
    rng = np.random.default_rng(100 + seed)
    n, t_stop = 16, 3_000.0
    ch, t = _random_record(rng, n, t_stop)
    fed = OnlineBurstDetector(n)
    expected = _stream(ch, t, fed, 10.0, t_stop)
    added = OnlineBurstDetector(n)
    events = []
    for w0 in np.arange(0.0, t_stop + 100.0, 100.0):  # what the hub does: add, then advance
        sel = np.flatnonzero((t >= w0) & (t < w0 + 100.0))
        for piece in np.array_split(sel, 4):
            added.add(ch[piece], t[piece])
        events += added.advance(w0 + 100.0)
    events += added.flush()
    assert np.array_equal(added.bursts, fed.bursts)
    assert sorted(map(repr, events)) == sorted(map(repr, expected))


def test_adds_must_keep_time_order_and_a_window_end_must_follow_them():
    det = OnlineBurstDetector(4)
    det.add([1, 2], [5.0, 7.0])
    with pytest.raises(AnalysisInputError, match="previous window end"):
        det.add([1], [6.0])
    with pytest.raises(AnalysisInputError, match="until_ms must be >= the last spike time 7.0"):
        det.advance(6.5)
    assert det.advance(8.0) == []


def test_a_channel_firing_more_spikes_than_its_buffer_holds_at_first_loses_none():
    # 10 kHz on channel 0 for 50 ms, fed at once: far more spikes than QUEUE_START.
    ch = np.zeros(500, np.int64)
    t = np.arange(500) * 0.1
    det = OnlineBurstDetector(2)
    events = det.feed(ch[:250], t[:250]) + det.feed(ch[250:], t[250:], until_ms=60.0)
    events += det.flush()
    assert np.array_equal(det.bursts, detect_bursts(ch, t))
    assert events[0] == Burst(0, 0.0, float(t[-1]), 500)
