"""Hand-made spike trains with known answers, shared by the analysis tests."""

import numpy as np


def merge(*trains):
    """Merge (channel, t_ms) pairs into one time-sorted record."""
    ch = np.concatenate([np.asarray(c, dtype=np.uint32) for c, _ in trains])
    t = np.concatenate([np.asarray(t, dtype=np.float64) for _, t in trains])
    order = np.argsort(t, kind="stable")
    return ch[order], t[order]


def network_burst(channels, start_ms, duration_ms, isi_ms=5.0):
    """Every channel in ``channels`` bursts from ``start_ms`` to ``start_ms + duration_ms``
    (regular spikes ``isi_ms`` apart, the last one exactly at the end)."""
    n_spikes = int(np.ceil(duration_ms / isi_ms)) + 1
    t = np.linspace(start_ms, start_ms + duration_ms, n_spikes)
    chans = np.asarray(channels)
    return merge((np.repeat(chans, n_spikes), np.tile(t, chans.size)))


def sparse_background(n_channels, t_stop_ms, rate_hz, seed=0, min_isi_ms=25.0):
    """Spikes that never burst: a regular train per channel with a random phase, ISI > 20 ms."""
    rng = np.random.default_rng(seed)
    period = max(1000.0 / rate_hz, min_isi_ms)
    chans, times = [], []
    for c in range(n_channels):
        t = np.arange(rng.uniform(0, period), t_stop_ms, period)
        chans.append(np.full(t.size, c))
        times.append(t)
    return np.concatenate(chans), np.concatenate(times)
