"""Batch comparison of experiment conditions over several seeds (the paper's Figure 9).

``neuvision compare A.toml B.toml --seeds 8`` runs every condition with seeds
1..8, each run a whole ``neuvision run`` in its own process group (so runs go
side by side, each with its own free port), up to ``--jobs`` at once. It then
reads every run's ``summary.json`` and writes, into the comparison folder:
``compare.json`` (every run's metrics, and mean ± s.d. per condition),
``compare.md`` (the table), and ``trajectories.png``/``.svg`` (all paths, one
row per condition).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from hub.config import load_config
from hub.record import new_run_dir, read_run
from lab.behaviour import world_of
from lab.postrun import SUMMARY_FILE
from sim_robot.render import draw_world

# Behaviour metrics shown in the table, in order, with how to print them.
METRICS = (
    ("obstacle_entries", "obstacle entries", "{:.2f}"),
    ("arena_exits", "arena exits", "{:.2f}"),
    ("time_in_obstacles_s", "time in obstacles (s)", "{:.2f}"),
    ("time_outside_arena_s", "time outside arena (s)", "{:.2f}"),
    ("distance_m", "distance (m)", "{:.3f}"),
    ("mean_speed_mps", "mean speed (m/s)", "{:.4f}"),
    ("coverage_fraction", "arena visited (fraction)", "{:.3f}"),
)


@dataclass
class Job:
    config: str
    name: str
    seed: int
    runs_dir: Path
    popen: subprocess.Popen | None = None
    run_dir: Path | None = None
    status: int | None = None


def compare(
    configs: list[str],
    seeds: int,
    out_dir: Path | None = None,
    jobs: int | None = None,
    overrides: list[str] = (),
) -> dict:
    """Run every config × seed, then tabulate and draw.

    Parameters
    ----------
    configs : list of str
        Experiment files, one per condition (distinct ``experiment.name`` values).
    seeds : int
        Seeds 1..seeds for each condition.
    out_dir : Path, optional
        Default a new folder under ``runs/``.
    jobs : int, optional
        Runs at once; default the number of CPUs.
    overrides : list of str
        ``--set`` items applied to every run.

    Returns
    -------
    dict
        ``conditions``, ``stats`` (per condition and metric: mean, s.d., n), ``runs``,
        ``figures`` and ``out_dir``; also written as ``compare.json``.
    """
    names = [load_config(c, list(overrides)).experiment.name for c in configs]
    if len(set(names)) != len(names):
        raise SystemExit(f"conditions need distinct experiment.name values, got {names}")
    out_dir = out_dir or new_run_dir("runs", "compare-" + "-vs-".join(names))
    out_dir.mkdir(parents=True, exist_ok=True)
    queue = [
        Job(c, n, seed, out_dir / n / f"seed{seed}")
        for c, n in zip(configs, names, strict=True)
        for seed in range(1, seeds + 1)
    ]
    _run_all(queue, jobs or os.cpu_count() or 1, list(overrides))
    result = _tabulate(queue, names)
    (out_dir / "compare.json").write_text(json.dumps(result, indent=2))
    table = format_table(result, names)
    (out_dir / "compare.md").write_text(table + "\n")
    print(table)
    figure = _draw(queue, names, out_dir)
    result["figures"] = [p.name for p in figure]
    result["out_dir"] = str(out_dir)
    print(f"neuvision: comparison in {out_dir}", file=sys.stderr)
    return result


def _run_all(queue: list[Job], jobs: int, overrides: list[str]) -> None:
    pending, running, done = list(queue), [], 0
    try:
        while pending or running:
            while pending and len(running) < jobs:
                job = pending.pop(0)
                job.runs_dir.mkdir(parents=True, exist_ok=True)
                cmd = [sys.executable, "-m", "hub.cli", "run", job.config, "--quiet"]
                cmd += ["--seed", str(job.seed), "--runs-dir", str(job.runs_dir)]
                for item in overrides:
                    cmd += ["--set", item]
                log = open(job.runs_dir / "run.log", "wb")
                job.popen = subprocess.Popen(
                    cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
                )
                log.close()
                running.append(job)
            time.sleep(0.2)
            for job in [j for j in running if j.popen.poll() is not None]:
                running.remove(job)
                done += 1
                job.status = job.popen.returncode
                folders = [p for p in job.runs_dir.iterdir() if p.is_dir()]
                job.run_dir = folders[0] if folders else None
                print(
                    f"[{done}/{len(queue)}] {job.name} seed {job.seed}: "
                    + ("completed" if job.status == 0 else f"FAILED (status {job.status})"),
                    file=sys.stderr,
                    flush=True,
                )
    except KeyboardInterrupt:
        for job in running:
            job.popen.send_signal(2)
        for job in running:
            job.popen.wait()
        raise


def _summary(job: Job) -> dict | None:
    if job.status != 0 or job.run_dir is None:
        return None
    path = job.run_dir / SUMMARY_FILE
    return json.loads(path.read_text()) if path.exists() else None


def _tabulate(queue: list[Job], names: list[str]) -> dict:
    runs, stats = [], {}
    for name in names:
        rows = []
        for job in (j for j in queue if j.name == name):
            summary = _summary(job)
            entry = {"seed": job.seed, "run_dir": str(job.run_dir), "ok": summary is not None}
            if summary:
                entry["behaviour"] = summary.get("behaviour", {})
                entry["x_realtime"] = summary["timing"].get("x_realtime")
                rows.append(entry["behaviour"])
            runs.append({"condition": name, **entry})
        stats[name] = {key: _stats([r[key] for r in rows if key in r]) for key, _, _ in METRICS}
    return {"conditions": names, "stats": stats, "runs": runs}


def _stats(values: list[float]) -> dict:
    """Mean, s.d. and count of one metric over the runs that have it (a body whose world is
    unknown has path metrics only)."""
    return {
        "mean": float(np.mean(values)) if values else None,
        "sd": float(np.std(values, ddof=1)) if len(values) > 1 else None,
        "n": len(values),
    }


def format_table(result: dict, names: list[str]) -> str:
    """The mean ± s.d. table, one row per metric, one column per condition.

    Parameters
    ----------
    result : dict
        From `compare` (its ``stats``).
    names : list of str
        The conditions, in column order.

    Returns
    -------
    str
        A Markdown table; a metric no run has shows "—".
    """
    head = "| metric | " + " | ".join(names) + " |"
    lines = [head, "|---" * (len(names) + 1) + "|"]
    for key, label, fmt in METRICS:
        cells = []
        for name in names:
            s = result["stats"][name][key]
            if s["mean"] is None:
                cells.append("—")
            else:
                sd = "" if s["sd"] is None else " ± " + fmt.format(s["sd"])
                cells.append(fmt.format(s["mean"]) + sd + f" (n={s['n']})")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _draw(queue: list[Job], names: list[str], out_dir: Path) -> list[Path]:
    seeds = sorted({j.seed for j in queue})
    fig = Figure(figsize=(2.2 * len(seeds), 2.4 * len(names)), layout="constrained")
    axes = fig.subplots(len(names), len(seeds), squeeze=False)
    for row, name in enumerate(names):
        for col, seed in enumerate(seeds):
            ax = axes[row][col]
            ax.set_axis_off()
            job = next(j for j in queue if j.name == name and j.seed == seed)
            if job.status != 0 or job.run_dir is None:
                ax.set_title(f"{name} s{seed}: failed", fontsize=7)
                continue
            rec = read_run(job.run_dir)
            world = world_of(rec.manifest.get("config", {}))
            if world is None:
                continue
            t_s, poses = rec.trajectory()
            draw_world(world, ax)
            ax.scatter(poses[:, 0], poses[:, 1], c=t_s, s=0.3, cmap="viridis")
            ax.set_title(f"{name} seed {seed}", fontsize=7)
    paths = []
    for suffix in (".png", ".svg"):
        path = out_dir / f"trajectories{suffix}"
        fig.savefig(path, dpi=130)
        paths.append(path)
    return paths
