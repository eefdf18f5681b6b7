"""Benchmark of the full closed loop: hub, 1024-neuron culture and arena, three processes.

1. Lockstep speed of configs/closed_loop.toml (dt 0.1 ms, 10 ms period) as simulated/wall
   time, and where the wall time goes: the culture's and the arena's time inside their
   step (measured by the endpoints themselves), and the hub's busy time (wall time minus
   the time the hub spent waiting for replies), and the CPU time per step of each
   process: on a machine with few cores, the loop is bound by their sum.
2. A realtime run at a 10 ms period: late steps and the lateness of step starts.

    python bench/closed_loop.py                 # 60 s lockstep + 60 s realtime
    python bench/closed_loop.py --seconds 20
    python bench/closed_loop.py --realtime-priority 0   # realtime under the ordinary scheduler

The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.host import StealMeter, child_run, end_children_on_signal  # noqa: E402


def run(mode: str, seconds: float, runs_dir: Path, *extra: str) -> tuple[dict, float]:
    """One ``neuvision run``: its manifest and the CPU steal share while it ran."""
    cmd = [sys.executable, "-m", "hub.cli", "run", "configs/closed_loop.toml", "--quiet", *extra]
    cmd += ["--mode", mode, "--duration-s", str(seconds), "--runs-dir", str(runs_dir)]
    cmd += ["--session", f"bench-closed-loop-{mode}"]
    with StealMeter() as steal:
        proc = child_run(cmd, cwd=ROOT)
    if proc.returncode != 0:
        raise SystemExit(f"{mode} run failed:\n{proc.stderr[-2000:]}")
    (run_dir,) = [p for p in runs_dir.iterdir() if p.is_dir()]
    return json.loads((run_dir / "manifest.json").read_text()), steal.share


def _scheduling(s: dict) -> str:
    """``fifo 10`` or ``normal``: the hub's threads during a realtime run."""
    return f"fifo {s['priority']}" if s["policy"] == "fifo" else "normal"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per run")
    parser.add_argument(
        "--realtime-priority", type=int, help="loop.realtime_priority of the realtime run"
    )
    args = parser.parse_args()
    end_children_on_signal()
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        m, steal = run("lockstep", args.seconds, Path(tmp) / "lockstep")
    t, ep = m["timing"], m["endpoints"]
    wall = t["wall_s"]
    shares = {
        "share_network": ep["culture"]["busy_s"] / wall,
        "share_arena": ep["body"]["busy_s"] / wall,
        "share_hub": t["hub_busy_s"] / wall,
    }
    print(
        f"lockstep {args.seconds:g} s simulated in {wall:.2f} s: {t['x_realtime']:.1f}x real time, "
        f"{t['steps_per_s']:.0f} steps/s, step median {t['step_ms_median']:.3f} ms "
        f"(CPU steal {steal:.1%})"
    )
    out["lockstep_steal_share"] = round(steal, 4)
    print(
        "  wall time shares: network {share_network:.1%}, arena {share_arena:.1%}, "
        "hub {share_hub:.1%} (the rest: messages in flight, process wake-ups)".format(**shares)
    )
    n = t["steps"]
    cpu_us = {
        "hub": t["hub_cpu_s"] / n * 1e6,
        "network": ep["culture"]["cpu_s"] / n * 1e6,
        "arena": ep["body"]["cpu_s"] / n * 1e6,
    }
    total_us = sum(cpu_us.values())
    print(
        "  CPU per step (each process, all its threads): "
        + ", ".join(f"{k} {v:.0f} us" for k, v in cpu_us.items())
        + f"; total {total_us:.0f} us = {total_us / (wall / n * 1e6):.2f} of the "
        f"{os.cpu_count()} cores busy"
    )
    out["x_realtime_lockstep"] = round(t["x_realtime"], 2)
    out.update({f"cpu_us_per_step_{k}": round(v, 1) for k, v in cpu_us.items()})
    out.update({k: round(v, 4) for k, v in shares.items()})
    with tempfile.TemporaryDirectory() as tmp:
        extra = []
        if args.realtime_priority is not None:
            extra = ["--set", f"loop.realtime_priority={args.realtime_priority}"]
        m, steal = run("realtime", args.seconds, Path(tmp) / "realtime", *extra)
    t = m["timing"]
    sched = t["scheduling"]
    print(
        f"realtime 10 ms ({_scheduling(sched)}), {t['steps']} steps: late steps "
        f"{t['late_steps']}, lateness median "
        f"{t['lateness_ms_median']:.3f} ms, p99 {t['lateness_ms_p99']:.3f} ms, "
        f"max {t['lateness_ms_max']:.3f} ms; missing {m['counts']['missing']}; "
        f"CPU steal {steal:.1%}"
    )
    out["rt10_steal_share"] = round(steal, 4)
    out["rt10_late_steps"] = t["late_steps"]
    out["rt10_p99_lateness_ms"] = round(t["lateness_ms_p99"], 4)
    out["rt10_median_lateness_ms"] = round(t["lateness_ms_median"], 4)
    out["rt10_max_lateness_ms"] = round(t["lateness_ms_max"], 3)
    out["rt_scheduling"] = _scheduling(sched)
    out["seconds"] = args.seconds
    print(json.dumps(out))


if __name__ == "__main__":
    main()
