"""Live burst detection finds bursts and network bursts on the spike stream, step by step."""

import numpy as np
import pytest

from hub.analysis.bursts import BurstParams
from hub.analysis.network_bursts import NetworkBurstParams
from hub.config import ConfigError, load_config
from hub.live_bursts import LiveBursts
from hub.loop import Hub
from hub.protocol import SpikeBatch
from tests.endpoints import EchoBody, EchoCulture
from tests.windows import RUN

PERIOD_MS = 10.0
# Channel ids need not be 0..n-1: a real MEA names its electrodes.
CHANNELS = np.array([12, 13, 21, 87])


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
def test_a_planted_network_burst_is_found_once_however_often_it_is_fed(every_ms):
    live = LiveBursts(CHANNELS, BurstParams(), NetworkBurstParams(), every_ms)
    found = []
    for batch in _batches(PLANTED, 60):
        live.add(batch)
        if live.due:
            found += live.work()
    found += live.finish()  # the end of the run feeds the rest
    assert live.bursts == 3 and live.network_bursts == 1
    (nb,) = found
    assert nb.start_ms == pytest.approx(100.0) and nb.end_ms == pytest.approx(119.0)
    assert sorted(nb.channels) == [0, 1, 2]  # detector indices of channels 12, 13, 21


def test_a_network_burst_under_way_is_seen_before_it_is_complete():
    live = LiveBursts(CHANNELS, BurstParams(), NetworkBurstParams(), 0.0)
    onsets, completed_at = [], None
    for batch in _batches(PLANTED, 60):
        live.add(batch)
        if live.work():
            completed_at = live.until_ms
        if live.under_way() is not None and completed_at is None:
            onsets.append((live.until_ms, live.under_way()))
    # Seen while the bursts go on; at its third channel's first spike (two are enough of
    # four: 30 %), and before the network burst is complete.
    first_seen_ms, onset_ms = onsets[0]
    assert onset_ms == pytest.approx(102.0)
    assert first_seen_ms < completed_at


def test_live_analysis_can_be_switched_off_and_its_parameters_are_checked():
    assert Hub(load_config(None, ["online.enabled=false"])).online is None
    hub = Hub(load_config(None, ["online.network.min_fraction=2.0"]))
    with pytest.raises(ConfigError, match="online.network"):
        hub.prepare({"body": EchoBody().describe(), "culture": EchoCulture().describe()})
