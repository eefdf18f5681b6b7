"""The hub detects bursts and network bursts on the live spike stream, step by step."""

import numpy as np
import pytest

from hub.config import ConfigError, load_config
from hub.loop import Hub
from hub.protocol import SpikeBatch
from tests.endpoints import EchoBody, EchoCulture

PERIOD_MS = 10.0


def _hub(*overrides):
    hub = Hub(load_config(None, list(overrides)))
    hub.descriptions = {"body": EchoBody().describe(), "culture": EchoCulture().describe()}
    culture = hub.descriptions["culture"]
    hub._channel_index = np.zeros(int(culture.channel.max()) + 1, np.int64)
    hub._channel_index[culture.channel] = np.arange(culture.channel.size)
    hub._build_schemes()
    return hub


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
            t0_s=t0 / 1e3,
            t1_s=(t0 + PERIOD_MS) / 1e3,
            channel=channel[inside],
            t_ms=t_ms[inside] - t0,
        )


def test_a_planted_network_burst_is_detected_once_and_counted():
    # Channels 0-2 of 4 each fire 4 spikes 5 ms apart starting near 100 ms: a network burst.
    planted = {c: [100 + 2 * c + 5 * i for i in range(4)] for c in range(3)}
    planted[3] = [30.0, 400.0]  # lone spikes elsewhere
    hub = _hub()
    for batch in _batches(planted, 60):
        hub.k = batch.step
        hub._analyse_online(batch)
    hub._analyse_online(None, flush=True)
    assert hub.bursts == 3
    assert hub.network_bursts == 1
    assert hub._status().extra["network_bursts"] == 1


def test_online_analysis_can_be_switched_off_and_its_parameters_are_checked():
    assert _hub("online.enabled=false").online is None
    with pytest.raises(ConfigError, match="online.network"):
        _hub("online.network.min_fraction=2.0")
