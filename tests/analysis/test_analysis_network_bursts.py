"""Network bursts: at least 30 % of channels bursting at once."""

import numpy as np
import pytest

from hub.analysis.bursts import detect_bursts
from hub.analysis.network_bursts import (
    NetworkBurstParams,
    detect_network_bursts,
    evoked_mask,
    inter_burst_intervals_ms,
)
from hub.analysis.spikes import AnalysisInputError
from tests.analysis.analysis_synth import merge, network_burst, sparse_background


def test_planted_network_burst_has_known_time_duration_and_participants():
    n = 20
    bg = sparse_background(n, 10_000.0, rate_hz=2.0)
    nb = network_burst(range(8), start_ms=4_000.0, duration_ms=70.0)  # 40 % of channels
    ch, t = merge(bg, nb)
    nbs = detect_network_bursts(detect_bursts(ch, t), n)
    assert len(nbs) == 1
    assert nbs.start_ms[0] == pytest.approx(4_000.0)
    assert nbs.duration_ms[0] == pytest.approx(70.0)
    assert nbs.channels[0].tolist() == list(range(8))


def test_too_few_channels_is_not_a_network_burst():
    ch, t = network_burst(range(5), 1_000.0, 70.0)  # 25 % of 20
    assert len(detect_network_bursts(detect_bursts(ch, t), 20)) == 0
    p = NetworkBurstParams(min_fraction=0.25)
    assert len(detect_network_bursts(detect_bursts(ch, t), 20, p)) == 1


def test_network_burst_extent_runs_from_first_to_last_participating_spike():
    # 4 channels of 10: two burst over [0, 50], two over [30, 100] -> >= 3 only on [30, 50]
    ch, t = merge(network_burst([0, 1], 0.0, 50.0), network_burst([2, 3], 30.0, 70.0))
    nbs = detect_network_bursts(detect_bursts(ch, t), 10)
    # the core is the time at >= 30 %; the duration is the extent of the bursts overlapping it
    assert (nbs.core_start_ms.tolist(), nbs.core_end_ms.tolist()) == ([30.0], [50.0])
    assert (nbs.start_ms.tolist(), nbs.end_ms.tolist()) == ([0.0], [100.0])
    assert nbs.duration_ms.tolist() == [100.0] and nbs.core_duration_ms.tolist() == [20.0]
    assert nbs.channels[0].tolist() == [0, 1, 2, 3]


def test_bursts_not_overlapping_the_core_do_not_widen_the_extent():
    # channels 0-2 burst over [100, 160]; channel 3 bursts just before, channel 4 just after
    ch, t = merge(
        network_burst([0, 1, 2], 100.0, 60.0),
        network_burst([3], 40.0, 50.0),
        network_burst([4], 170.0, 50.0),
    )
    nbs = detect_network_bursts(detect_bursts(ch, t), 10)
    assert (nbs.start_ms.tolist(), nbs.end_ms.tolist()) == ([100.0], [160.0])
    assert nbs.channels[0].tolist() == [0, 1, 2]


def test_segments_closer_than_merge_gap_are_one_network_burst():
    # each channel bursts twice, 25 ms apart (two bursts per channel: the gap exceeds 20 ms)
    ch, t = merge(network_burst([0, 1, 2], 0.0, 40.0), network_burst([0, 1, 2], 65.0, 40.0))
    bursts = detect_bursts(ch, t)
    assert bursts.size == 6
    assert len(detect_network_bursts(bursts, 6, NetworkBurstParams(merge_gap_ms=20.0))) == 2
    merged = detect_network_bursts(bursts, 6, NetworkBurstParams(merge_gap_ms=25.0))
    assert (merged.start_ms.tolist(), merged.end_ms.tolist()) == ([0.0], [105.0])


def test_one_channel_and_edges_of_record():
    ch, t = network_burst([0], 0.0, 30.0)
    nbs = detect_network_bursts(detect_bursts(ch, t), 1)
    assert nbs.start_ms.tolist() == [0.0] and nbs.end_ms.tolist() == [30.0]
    assert len(detect_network_bursts(detect_bursts([], []), 5)) == 0


def test_ibi_and_evoked_split():
    starts = [1_000.0, 3_000.0, 6_000.0]
    ch, t = merge(*[network_burst(range(4), s, 60.0) for s in starts])
    nbs = detect_network_bursts(detect_bursts(ch, t), 10)
    assert inter_burst_intervals_ms(nbs).tolist() == [2_000.0, 3_000.0]
    assert evoked_mask(nbs, [950.0, 5_000.0], max_latency_ms=100.0).tolist() == [
        True,
        False,
        False,
    ]
    assert nbs.select([False, True, True]).start_ms.tolist() == [3_000.0, 6_000.0]


def test_a_burst_already_running_at_the_pulse_does_not_unmake_an_evoked_network_burst():
    # one channel of 10 bursts from 995 ms; at 1000 ms a pulse, from 1015 ms four more burst
    # together: the extent starts before the pulse, the core (>= 3 of 10) after it
    ch, t = merge(network_burst([0], 995.0, 40.0), network_burst([1, 2, 3, 4], 1_015.0, 40.0))
    nbs = detect_network_bursts(detect_bursts(ch, t), 10)
    assert nbs.start_ms.tolist() == [995.0] and nbs.core_start_ms[0] >= 1_015.0
    assert evoked_mask(nbs, [1_000.0], max_latency_ms=100.0).tolist() == [True]
    assert evoked_mask(nbs, [1_000.0], max_latency_ms=10.0).tolist() == [False]


def test_bad_parameters_are_named():
    with pytest.raises(AnalysisInputError, match="network_bursts.min_fraction"):
        NetworkBurstParams(min_fraction=0.0)
    with pytest.raises(AnalysisInputError, match="n_channels"):
        detect_network_bursts(detect_bursts([7, 7, 7], [0.0, 1.0, 2.0]), 5)
    with pytest.raises(AnalysisInputError, match="dtype"):
        detect_network_bursts(np.zeros(3), 5)


def test_ibi_is_timed_by_the_cores_when_a_long_burst_stretches_every_extent():
    # a closed loop's stimulated channel: one burst of 10 s, every 10 ms
    long_ch, long_t = network_burst([9], 0.0, 10_000.0)
    starts = [2_000.0, 5_000.0, 9_000.0]
    ch, t = merge((long_ch, long_t), *[network_burst(range(4), s, 60.0) for s in starts])
    nbs = detect_network_bursts(detect_bursts(ch, t), 10)
    assert nbs.start_ms.tolist() == [0.0, 0.0, 0.0]  # each extent starts with the long burst
    assert inter_burst_intervals_ms(nbs) == pytest.approx([3_000.0, 4_000.0], abs=10.0)
