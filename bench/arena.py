"""Benchmark: one arena step plus a full sensor read (issue 4: <= 50 us median).

World: ``configs/worlds/bench16.toml`` (the paper's arena and obstacles, a 16-range-finder
robot, pass-through physics). Each timed step is ``arena.step(left, right, 0.01)`` followed
by ``arena.read_sensors()``, with wheel speeds that change every 0.5 s; a robot that leaves the
arena is put back at its start pose (untimed). For reference it also times the same sensor read
done with pymunk segment queries, and a step in the solid-walled khepera4 world.

Usage: ``python bench/arena.py [--steps N]``. The last line is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from sim_robot import Arena
from sim_robot.physics import pymunk_ranges

WORLDS = Path(__file__).resolve().parents[1] / "configs" / "worlds"
DT_S = 0.01


def time_steps(arena: Arena, n_steps: int, seed: int = 0) -> np.ndarray:
    """Per-step wall time (us) of step + read_sensors."""
    rng = np.random.default_rng(seed)
    wheels = rng.uniform(-0.05, 0.2, size=(n_steps // 50 + 1, 2))
    out = np.empty(n_steps)
    clock = time.perf_counter_ns
    for k in range(n_steps):
        left, right = wheels[k // 50]
        t0 = clock()
        arena.step(left, right, DT_S)
        arena.read_sensors()
        out[k] = (clock() - t0) / 1e3
        if arena.outside:
            arena.reset()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=50_000)
    args = parser.parse_args()

    arena = Arena.from_toml(WORLDS / "bench16.toml")
    time_steps(arena, 2_000)  # warm-up: numba compilation / cache load
    arena.reset()
    us = time_steps(arena, args.steps)
    median, p99 = float(np.median(us)), float(np.percentile(us, 99))
    hits = 0
    arena.reset()
    for _ in range(200):
        arena.step(0.1, 0.12, DT_S)
        hits += int(np.sum(arena.read_sensors() < arena.body.max_range_m))

    # reference: the same 16-sensor read with pymunk segment queries
    ref = np.empty(2_000)
    for k in range(ref.size):
        t0 = time.perf_counter_ns()
        pymunk_ranges(arena.space, arena.world, arena.pose)
        ref[k] = (time.perf_counter_ns() - t0) / 1e3
    pymunk_read_us = float(np.median(ref))

    solid = Arena.from_toml(WORLDS / "khepera4.toml")
    time_steps(solid, 500)
    solid.reset()
    solid_us = time_steps(solid, 5_000)

    print(
        f"world: bench16 ({arena.body.n_sensors} range finders, "
        f"{len(arena.world.obstacles)} obstacles, pass-through), dt = {DT_S} s"
    )
    print(
        f"step + read_sensors over {args.steps} steps: median {median:.2f} us, "
        f"p99 {p99:.2f} us, mean {us.mean():.2f} us (target: median <= 50 us)"
    )
    print(f"sensor hits in 200 sample steps: {hits} of {200 * arena.body.n_sensors} rays")
    print(f"reference 16-ray read with pymunk segment_query_first: median {pymunk_read_us:.1f} us")
    print(
        f"khepera4 solid world (8 sensors, pymunk collisions) step + read: median "
        f"{np.median(solid_us):.2f} us, p99 {np.percentile(solid_us, 99):.2f} us"
    )
    print(
        json.dumps(
            {
                "step_us_median": round(median, 3),
                "step_us_p99": round(p99, 3),
                "step_us_mean": round(float(us.mean()), 3),
                "n_steps": args.steps,
                "n_sensors": arena.body.n_sensors,
                "pymunk_read_us_median": round(pymunk_read_us, 3),
                "solid_step_us_median": round(float(np.median(solid_us)), 3),
                "target_us": 50.0,
                "pass": median <= 50.0,
                "python": platform.python_version(),
            }
        )
    )


if __name__ == "__main__":
    main()
