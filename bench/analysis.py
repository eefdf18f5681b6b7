"""Benchmark: offline analysis of a synthetic 15-minute, 1024-channel, ~3-million-spike record.

The record is Poisson background (about 2.3 spikes/s per channel) plus network bursts about 7 per
minute, each one a wave spreading from a random origin over 32 x 32 grid positions, with ~70 %
of channels bursting 70 ms. Also times the online detector on the first minute, fed in 10 ms
windows as the hub would. Prints readable figures; the LAST line is one JSON object with
``analyze_s_3M_spikes``.

Run: ``.venv/bin/python bench/analysis.py``
"""

from __future__ import annotations

import json
import time

import numpy as np

from hub.analysis.metrics import analyze
from hub.analysis.online import OnlineBurstDetector

N_CHANNELS = 1024
T_STOP_MS = 15 * 60_000.0


def synthetic_record(seed: int = 0):
    """(channel, t_ms, cell_type, x_um, y_um, stim_ms) of the benchmark record."""
    rng = np.random.default_rng(seed)
    side = 32
    x_um = 25.0 * (np.arange(N_CHANNELS) % side)
    y_um = 25.0 * (np.arange(N_CHANNELS) // side)
    cell_type = (rng.random(N_CHANNELS) < 0.2).astype(np.uint8)
    n_bg = rng.poisson(2.3 * N_CHANNELS * T_STOP_MS / 1000.0)
    chans = [rng.integers(0, N_CHANNELS, n_bg)]
    times = [rng.uniform(0.0, T_STOP_MS, n_bg)]
    nb_starts = np.sort(rng.uniform(0.0, T_STOP_MS - 200.0, int(7 * T_STOP_MS / 60_000.0)))
    for start in nb_starts:
        part = np.flatnonzero(rng.random(N_CHANNELS) < 0.7)
        origin = rng.integers(0, N_CHANNELS)
        dist = np.hypot(x_um[part] - x_um[origin], y_um[part] - y_um[origin])
        onset = start + 30.0 * dist / dist.max()
        n_sp = rng.integers(8, 16, part.size)
        isi = rng.uniform(2.0, 5.0, n_sp.sum())
        first = np.cumsum(n_sp) - n_sp
        t_rel = np.cumsum(isi) - np.repeat(np.cumsum(isi)[first] - isi[first], n_sp)
        chans.append(np.repeat(part, n_sp))
        times.append(np.repeat(onset, n_sp) + t_rel)
    ch = np.concatenate(chans).astype(np.uint32)
    t = np.concatenate(times)
    order = np.argsort(t, kind="stable")
    stim_ms = np.arange(1_000.0, T_STOP_MS, 5_000.0)  # 0.2 Hz
    return ch[order], t[order], cell_type, x_um, y_um, stim_ms


def main() -> None:
    t0 = time.perf_counter()
    ch, t, cell_type, x_um, y_um, stim_ms = synthetic_record()
    gen_s = time.perf_counter() - t0
    print(
        f"synthetic record: {t.size:,} spikes, {N_CHANNELS} channels, "
        f"{T_STOP_MS / 60_000:.0f} min (generated in {gen_s:.2f} s)"
    )

    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        res = analyze(ch, t, N_CHANNELS, 0.0, T_STOP_MS, cell_type, x_um, y_um, stim_ms)
        best = min(best, time.perf_counter() - t0)
    m = res.metrics
    print(f"analyze (all metrics, bursts, network bursts, PSTH, CATs): best of 3 = {best:.2f} s")
    for key in (
        "mfr_hz",
        "mfr_sd_hz",
        "mbr_per_min",
        "mnbr_per_min",
        "nb_duration_ms",
        "nb_duration_sd_ms",
        "n_bursts",
        "n_network_bursts",
        "cat_spread",
    ):
        print(f"  {key:>18} = {m[key]}")

    minute = t < 60_000.0
    c1, t1 = ch[minute], t[minute]
    det = OnlineBurstDetector(N_CHANNELS)
    edges = np.searchsorted(t1, np.arange(0.0, 60_010.0, 10.0))
    t0 = time.perf_counter()
    for k in range(edges.size - 1):
        det.feed(c1[edges[k] : edges[k + 1]], t1[edges[k] : edges[k + 1]], until_ms=10.0 * (k + 1))
    det.flush()
    online_s = time.perf_counter() - t0
    rate = t1.size / online_s
    offline = analyze(c1, t1, N_CHANNELS, 0.0, 60_000.0)
    same = np.array_equal(det.bursts, offline.bursts) and np.array_equal(
        det.network_bursts.start_ms, offline.network_bursts.start_ms
    )
    print(
        f"online detector, first minute in 10 ms windows: {t1.size:,} spikes in "
        f"{online_s:.2f} s ({rate:,.0f} spikes/s, {len(det.network_bursts)} network bursts)"
    )
    print(
        json.dumps(
            {
                "analyze_s_3M_spikes": round(best, 3),
                "n_spikes": int(t.size),
                "n_channels": N_CHANNELS,
                "duration_min": T_STOP_MS / 60_000.0,
                "online_spikes_per_s": round(rate),
                "online_equals_offline": bool(same),
            }
        )
    )


if __name__ == "__main__":
    main()
