"""Benchmark of the culture on NEST (``culture.kind = "nest"``) beside sim_network.

    .venv/bin/python bench/nest.py [--quick] [--seconds 10]

Each figure is measured in a fresh subprocess (NEST holds one network per process; the
peak RSS is that process's), which ends with the benchmark even if it is killed. Figures:

- ``x_realtime_1024_nest``: the culture (`CULTURE`) on NEST, 1 thread, the culture's own
  noise (the default), ``run()`` in 1 s calls, after a 1 s warm-up;
- ``x_realtime_1024_nest_10ms_calls`` and ``step_overhead_us``: the same in 10 ms calls
  (as the closed loop steps it); the overhead is the wall time per 10 ms step beyond the
  1 s calls' (Prepare, the Run calls, reading and emptying the spike recorder, Cleanup,
  the hand-off to the NEST thread), 300 steps each way, alternated;
- ``x_realtime_1024_nest_threads2`` and ``x_realtime_1024_nest_noise_generator``: with 2
  threads; with NEST's own (Gaussian) noise instead of the culture's;
- 100k (``--quick`` skips them): bench/network.py's ~100k-neuron network (`config_100k`,
  dt 1 ms, ~93 synapses per neuron) built and run on NEST with 2 threads
  (``build_s_100k_nest``, ``x_realtime_100k_nest_threads2``, and with NEST's noise
  ``x_realtime_100k_nest_threads2_noise_generator``) and on sim_network
  (``x_realtime_100k_sim_network``, one thread).

The host's CPU steal during each figure is printed beside it. The last line is one JSON
object.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.host import StealMeter, child_run, end_children_on_signal  # noqa: E402

#: The culture measured at 1024 neurons: the default (repoint it when the default changes).
CULTURE = ROOT / "configs" / "culture_1024.toml"


def _config(name: str):
    from sim_network import load_config

    if name == "culture":
        return load_config(CULTURE)
    if name == "100k":
        from bench.network import config_100k

        return config_100k()
    raise ValueError(name)


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_nest(config: str, threads: int, noise_source: str, seconds: float, warmup_s: float):
    """Build a network on NEST and time `seconds` of it in 1 s calls (in a subprocess)."""
    from sim_network.nest_backend import NestNetwork

    cfg = _config(config)
    t = time.perf_counter()
    net = NestNetwork(cfg, seed=1, threads=threads, noise_source=noise_source)
    build_s = time.perf_counter() - t
    net.run(warmup_s * 1000.0)
    n_spikes = 0
    chunk_ms = min(1000.0, seconds * 1000.0)
    with StealMeter() as steal:
        t = time.perf_counter()
        for _ in range(round(seconds * 1000.0 / chunk_ms)):
            n_spikes += len(net.run(chunk_ms))
        wall = time.perf_counter() - t
    return {
        "n_neurons": net.n_neurons,
        "synapses_per_neuron": net.n_connections / net.n_neurons,
        "build_s": build_s,
        "x_realtime": seconds / wall,
        "rate_hz": n_spikes / net.n_neurons / seconds,
        "steal": steal.share,
        "peak_rss_mb": _peak_rss_mb(),
    }


def step_overhead(steps: int = 300, repeats: int = 2) -> dict:
    """The culture on NEST in 10 ms calls against 1 s calls (in a subprocess)."""
    from sim_network.nest_backend import NestNetwork

    net = NestNetwork(_config("culture"), seed=1)
    net.run(1000.0)
    per_step = {"long": [], "short": []}
    with StealMeter() as steal:
        for _ in range(repeats):
            t = time.perf_counter()
            for _ in range(steps // 100):
                net.run(1000.0)
            per_step["long"].append((time.perf_counter() - t) / steps)
            t = time.perf_counter()
            for _ in range(steps):
                net.run(10.0)
            per_step["short"].append((time.perf_counter() - t) / steps)
    long_s, short_s = (sum(v) / len(v) for v in per_step.values())
    return {
        "x_realtime_10ms_calls": 0.010 / short_s,
        "step_s": short_s,
        "overhead_us": (short_s - long_s) * 1e6,
        "steal": steal.share,
    }


def run_sim_network_100k(seconds: float) -> dict:
    """bench/network.py's 100k network on sim_network (in a subprocess)."""
    from bench.network import bench_100k

    with StealMeter() as steal:
        out = bench_100k(seconds)
    return {**out, "steal": steal.share}


def in_subprocess(func: str, *args) -> dict:
    code = (
        f"import json, sys; sys.path.insert(0, {str(ROOT)!r}); import bench.nest as b; "
        f"print(json.dumps(b.{func}(*{args!r})))"
    )
    out = child_run([sys.executable, "-c", code])
    if out.returncode:
        raise SystemExit(f"{func}{args} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _steal(r: dict) -> str:
    return f"steal {100 * r['steal']:.0f} %" if math.isfinite(r["steal"]) else "steal ?"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="skip the 100k networks")
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds (1024)")
    args = ap.parse_args()
    end_children_on_signal()
    s = args.seconds
    result: dict[str, float] = {}

    r = in_subprocess("run_nest", "culture", 1, "culture", s, 1.0)
    result["x_realtime_1024_nest"] = r["x_realtime"]
    print(
        f"1024 neurons on NEST, 1 thread, the culture's noise: {r['x_realtime']:6.2f}x real time "
        f"(rate {r['rate_hz']:.2f} Hz, built in {r['build_s']:.2f} s, {_steal(r)})"
    )
    o = in_subprocess("step_overhead")
    result["x_realtime_1024_nest_10ms_calls"] = o["x_realtime_10ms_calls"]
    result["step_overhead_us"] = o["overhead_us"]
    print(
        f"  in run(10 ms) calls: {o['x_realtime_10ms_calls']:6.2f}x real time, "
        f"{1e3 * o['step_s']:.2f} ms per step, of which {o['overhead_us']:.0f} µs stepping "
        f"overhead ({_steal(o)})"
    )
    for threads, noise, key, label in (
        (2, "culture", "x_realtime_1024_nest_threads2", "2 threads, the culture's noise"),
        (1, "nest", "x_realtime_1024_nest_noise_generator", "1 thread, NEST's noise_generator"),
    ):
        r = in_subprocess("run_nest", "culture", threads, noise, s, 1.0)
        result[key] = r["x_realtime"]
        print(f"  {label}: {r['x_realtime']:6.2f}x real time ({_steal(r)})")
    if not args.quick:
        secs = max(1.0, s / 5)
        r = in_subprocess("run_nest", "100k", 2, "culture", secs, 0.2)
        result["build_s_100k_nest"] = r["build_s"]
        result["x_realtime_100k_nest_threads2"] = r["x_realtime"]
        result["peak_rss_mb_100k_nest"] = r["peak_rss_mb"]
        print(
            f"{r['n_neurons']} neurons ({r['synapses_per_neuron']:.0f} synapses/neuron) on NEST, "
            f"2 threads, dt 1 ms: built in {r['build_s']:.1f} s, {r['x_realtime']:.3f}x real "
            f"time with the culture's noise (rate {r['rate_hz']:.2f} Hz, peak RSS "
            f"{r['peak_rss_mb']:.0f} MB, {_steal(r)})"
        )
        r = in_subprocess("run_nest", "100k", 2, "nest", secs, 0.2)
        result["x_realtime_100k_nest_threads2_noise_generator"] = r["x_realtime"]
        print(f"  with NEST's noise_generator: {r['x_realtime']:.3f}x real time ({_steal(r)})")
        r = in_subprocess("run_sim_network_100k", secs)
        result["x_realtime_100k_sim_network"] = r["x_realtime_dt1"]
        print(
            f"  on sim_network, 1 thread: built in {r['build_s']:.1f} s, "
            f"{r['x_realtime_dt1']:.2f}x real time (rate {r['rate_hz']:.2f} Hz, peak RSS "
            f"{r['peak_rss_mb']:.0f} MB, {_steal(r)})"
        )
    print(json.dumps({k: (round(v, 3) if math.isfinite(v) else None) for k, v in result.items()}))


if __name__ == "__main__":
    main()
