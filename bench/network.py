"""Benchmark of sim_network: simulated/wall time ratio, per-call overhead, build time, memory.

    .venv/bin/python bench/network.py [--quick] [--seconds 10]

Single-threaded (numba kernels are serial). Networks are the default culture config
(configs/culture_1024.toml) with the grid enlarged; the 100k network has wider connectivity
(~100 synapses per neuron) with weights scaled down to match (see `bench_100k`). The 100k
figures and the warm-compile time are measured in fresh subprocesses (peak RSS of that
process). The last line is one JSON object.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.host import child_run, end_children_on_signal  # noqa: E402
from sim_network import ConnectivityConfig, Network, load_config  # noqa: E402

CONFIG = ROOT / "configs" / "culture_1024.toml"


def sized(n_side: int, dt_ms: float, connectivity: ConnectivityConfig | None = None):
    base = load_config(CONFIG)
    return dataclasses.replace(
        base,
        dt_ms=dt_ms,
        layout=dataclasses.replace(base.layout, rows=n_side, cols=n_side),
        connectivity=connectivity or base.connectivity,
    )


def x_realtime(cfg, seconds: float, chunk_ms: float | None = None) -> tuple[float, float, Network]:
    """(simulated/wall ratio, mean firing rate in Hz, network) after a 1 s warm-up."""
    net = Network(cfg, seed=1)
    net.run(1000.0)
    n_spikes = 0
    wall = time.perf_counter()
    if chunk_ms is None:
        n_spikes = len(net.run(seconds * 1000.0))
    else:
        for _ in range(round(seconds * 1000.0 / chunk_ms)):
            n_spikes += len(net.run(chunk_ms))
    wall = time.perf_counter() - wall
    return seconds / wall, n_spikes / net.n_neurons / seconds, net


def per_call_us(net: Network, calls: int = 2000, period_ms: float = 10.0) -> float:
    """Mean wall time of run(period_ms), as the closed loop calls it."""
    t = time.perf_counter()
    for _ in range(calls):
        net.run(period_ms)
    return (time.perf_counter() - t) / calls * 1e6


def config_100k():
    """316² ≈ 100k neurons at dt = 1 ms: the culture with its connectivity widened to
    d_pc_um = 200 (≈ 100 synapses per neuron, 4× the culture's) and the weights scaled by
    1/4 so that the summed input per neuron stays comparable (bench/nest.py uses it too)."""
    base = load_config(CONFIG).connectivity
    scale = 0.25
    con = dataclasses.replace(
        base,
        d_pc_um=200.0,
        cutoff_um=1000.0,
        weight_exc_mv=tuple(w * scale for w in base.weight_exc_mv),
        weight_inh_mv=tuple(w * scale for w in base.weight_inh_mv),
    )
    return sized(316, 1.0, con)


def bench_100k(seconds: float) -> dict:
    """Build and run `config_100k` (called in a subprocess)."""
    cfg = config_100k()
    t = time.perf_counter()
    net = Network(cfg, seed=1)
    build_s = time.perf_counter() - t
    net.run(1000.0)
    t = time.perf_counter()
    n_spikes = len(net.run(seconds * 1000.0))
    x = seconds / (time.perf_counter() - t)
    return {
        "n_neurons": net.n_neurons,
        "synapses_per_neuron": net.synapses.n_synapses / net.n_neurons,
        "build_s": build_s,
        "x_realtime_dt1": x,
        "rate_hz": n_spikes / net.n_neurons / seconds,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }


def warm_compile() -> dict:
    """First-call time in a fresh process whose numba cache is already warm."""
    t0 = time.perf_counter()
    import sim_network.kernels  # noqa: F401

    cfg = sized(8, 0.1)
    net = Network(cfg, seed=1)
    t1 = time.perf_counter()
    net.run(1.0)
    t2 = time.perf_counter()
    return {"import_and_build_s": t1 - t0, "first_run_s": t2 - t1}


def in_subprocess(func: str, *args) -> dict:
    code = (
        f"import json, sys; sys.path.insert(0, {str(ROOT)!r}); import bench.network as b; "
        f"print(json.dumps(b.{func}(*{args!r})))"
    )
    out = child_run([sys.executable, "-c", code])
    if out.returncode:
        raise SystemExit(f"{func} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="skip the 100k network")
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per figure")
    args = ap.parse_args()
    end_children_on_signal()
    s = args.seconds
    result: dict[str, float] = {}
    Network(sized(4, 0.1), seed=0).run(1.0)  # compile or load the kernels before timing

    for n_side, dt, key in ((32, 0.1, "1024_dt01"), (32, 1.0, "1024_dt1")):
        x, rate, net = x_realtime(sized(n_side, dt), s)
        result[f"x_realtime_{key}"] = x
        print(f"1024 neurons, dt {dt} ms: {x:7.1f}x real time  (rate {rate:.2f} Hz, one run call)")
    x, rate, net = x_realtime(sized(32, 0.1), s, chunk_ms=10.0)
    result["x_realtime_1024_dt01_10ms_calls"] = x
    us = per_call_us(net)
    result["run_10ms_call_us_1024_dt01"] = us
    print(f"1024 neurons, dt 0.1 ms, run(10 ms) calls: {x:7.1f}x real time, {us:.0f} µs per call")
    for n_side, key in ((64, "4096_dt01"), (128, "16384_dt01")):
        secs = s if n_side == 64 else max(1.0, s / 4)
        x, rate, net = x_realtime(sized(n_side, 0.1), secs)
        result[f"x_realtime_{key}"] = x
        syn = net.synapses.n_synapses / net.n_neurons
        print(
            f"{net.n_neurons} neurons, dt 0.1 ms: {x:7.1f}x real time  "
            f"(rate {rate:.2f} Hz, {syn:.0f} synapses/neuron)"
        )
    if not args.quick:
        r = in_subprocess("bench_100k", max(2.0, s / 2))
        result["build_s_100k"] = r["build_s"]
        result["x_realtime_100k_dt1"] = r["x_realtime_dt1"]
        result["peak_rss_mb_100k"] = r["peak_rss_mb"]
        print(
            f"{r['n_neurons']} neurons ({r['synapses_per_neuron']:.0f} synapses/neuron): "
            f"built in {r['build_s']:.1f} s, {r['x_realtime_dt1']:.2f}x real time at dt 1 ms "
            f"(rate {r['rate_hz']:.2f} Hz), peak RSS {r['peak_rss_mb']:.0f} MB"
        )
    w = in_subprocess("warm_compile")
    result["warm_compile_s"] = w["first_run_s"]
    print(
        f"warm numba cache: first run() {w['first_run_s']:.3f} s "
        f"(import + build {w['import_and_build_s']:.2f} s)"
    )
    print(json.dumps({k: (round(v, 3) if math.isfinite(v) else None) for k, v in result.items()}))


if __name__ == "__main__":
    main()
