"""Batch comparison of experiment conditions over several seeds (the paper's Figure 9).

``neuvision compare A.toml B.toml --seeds 8`` runs every condition with seeds
1..8, each run a whole ``neuvision run`` in its own process group (so runs go
side by side, each with its own free port), up to ``--jobs`` at once. It then
reads every run's ``summary.json`` and writes, into the comparison folder:
``compare.json`` (every run's metrics, mean ± s.d. per condition, the tests),
``compare.md`` (the tables: mean ± s.d. with n, every failed run with its reason,
each seed's values, and a two-sided permutation test of each metric between the
first condition and each other), and ``trajectories.png``/``.svg`` (all paths,
one row per condition). A run that failed is never dropped silently: it is listed
with its exit status and last error line, and ``neuvision compare`` exits with
status 2.
"""

from __future__ import annotations

import datetime
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from hub.config import load_config
from hub.launch import NEUVISION
from hub.record import make_output_folder, new_run_dir, read_run
from lab.behaviour import world_of
from lab.experiment import check_hub_sections
from lab.postrun import SUMMARY_FILE
from lab.stats import permutation_test
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


class CompareError(ValueError):
    """A comparison that cannot be run as asked (seeds, jobs, conditions): one line."""


@dataclass
class Job:
    """One run of a comparison: a condition at one seed, a ``neuvision run`` of its own.

    ``runs_dir`` receives the run's folder and its ``run.log``; ``popen``, ``run_dir``,
    ``status`` and ``reason`` (empty: it completed with a summary) are set as it runs.
    """

    config: str
    name: str
    seed: int
    runs_dir: Path
    popen: subprocess.Popen | None = None
    run_dir: Path | None = None
    status: int | None = None
    reason: str = ""


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

    Raises
    ------
    CompareError
        ``seeds`` or ``jobs`` < 1, or two conditions of the same name; before any run.
    hub.record.OutputError
        ``out_dir`` cannot be made; before any run.
    """
    if seeds < 1:
        raise CompareError(f"--seeds must be >= 1 (seeds 1..N per condition), got {seeds}")
    if jobs is not None and jobs < 1:
        raise CompareError(f"--jobs must be >= 1, got {jobs}")
    cfgs = [load_config(c, list(overrides)) for c in configs]
    for cfg in cfgs:  # the endpoints' and the schemes' params too, before the first run
        cfg.resolved()
        check_hub_sections(cfg)
    names = [cfg.experiment.name for cfg in cfgs]
    if len(set(names)) != len(names):
        same = sorted({n for n in names if names.count(n) > 1})
        raise CompareError(
            f"conditions need distinct experiment.name values (each names its folder of "
            f"runs): {', '.join(same)} is more than one condition's; give each file a name "
            f"of its own"
        )
    external = [n for n, cfg in zip(names, cfgs, strict=True)
                if any(cfg.endpoint(r).launch != "local" for r in ("body", "culture"))]  # fmt: skip
    if external and (jobs or 0) != 1:
        # Their hubs listen where their external endpoints look: one at a time.
        print(f"neuvision: {', '.join(external)} has endpoints started elsewhere, on the "
              "config's bus address: runs one at a time", file=sys.stderr)  # fmt: skip
        jobs = 1
    if out_dir is not None:
        out_dir = make_output_folder(out_dir, "--out")
    else:
        out_dir = new_run_dir("runs", "compare-" + "-vs-".join(names), what="runs")
    queue = [
        Job(c, n, seed, out_dir / n / f"seed{seed}")
        for c, n in zip(configs, names, strict=True)
        for seed in range(1, seeds + 1)
    ]
    _run_all(queue, jobs or os.cpu_count() or 1, list(overrides))
    result = _tabulate(queue, names)
    # what each condition ran: its file, and what every run was given on top
    result["condition_files"] = {n: str(c) for n, c in zip(names, configs, strict=True)}
    result["overrides"] = list(overrides)
    (out_dir / "compare.json").write_text(json.dumps(result, indent=2))
    table = format_table(result, names)
    durations = sorted({f"{c.experiment.duration_s:g} s" for c in cfgs})
    given = "".join(f"- **{n}**: `{c}`\n" for n, c in result["condition_files"].items())
    also = ", ".join(f"`--set {o}`" for o in overrides) or "nothing"
    heading = (
        f"# {' vs '.join(names)}: {'seed 1' if seeds == 1 else f'seeds 1-{seeds}'}, runs of "
        f"{' / '.join(durations)} "
        f"(compared {datetime.date.today().isoformat()})\n\n"
        f"Conditions (each run's manifest holds its whole config):\n\n{given}\n"
        f"Given to every run: {also}.\n\n"
    )
    (out_dir / "compare.md").write_text(heading + table + "\n")
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
                cmd = [*NEUVISION, "run", job.config, "--quiet"]
                cmd += ["--seed", str(job.seed), "--runs-dir", str(job.runs_dir)]
                for item in overrides:
                    cmd += ["--set", item]
                with open(job.runs_dir / "run.log", "wb") as log:
                    job.popen = subprocess.Popen(
                        cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
                    )
                running.append(job)
            time.sleep(0.2)
            for job in [j for j in running if j.popen.poll() is not None]:
                running.remove(job)
                done += 1
                job.status = job.popen.returncode
                folders = [p for p in job.runs_dir.iterdir() if p.is_dir()]
                job.run_dir = folders[0] if folders else None
                if job.status != 0:
                    job.reason = f"exit status {job.status}: {_last_error(job)}"
                elif job.run_dir is None or not (job.run_dir / SUMMARY_FILE).exists():
                    job.reason = "no summary.json was written"
                print(
                    f"[{done}/{len(queue)}] {job.name} seed {job.seed}: "
                    + (f"FAILED ({job.reason})" if job.reason else "completed"),
                    file=sys.stderr,
                    flush=True,
                )
    except KeyboardInterrupt:
        for job in running:
            job.popen.send_signal(signal.SIGINT)
        for job in running:
            job.popen.wait()
        raise


def _last_error(job: Job) -> str:
    """The line of a failed run's log that says why (its last ``neuvision:`` or error line)."""
    try:
        lines = (job.runs_dir / "run.log").read_text(errors="replace").splitlines()
    except OSError:
        return "no log"
    lines = [line.strip() for line in lines if line.strip()]
    for line in reversed(lines):
        if "failed" in line or "error" in line.lower() or line.startswith("neuvision:"):
            return line[:300]
    return lines[-1][:300] if lines else "an empty log"


def _summary(job: Job) -> dict | None:
    if job.reason or job.run_dir is None:
        return None
    return json.loads((job.run_dir / SUMMARY_FILE).read_text())


def _tabulate(queue: list[Job], names: list[str]) -> dict:
    runs, stats = [], {}
    for name in names:
        rows = []
        for job in (j for j in queue if j.name == name):
            summary = _summary(job)
            entry = {"seed": job.seed, "run_dir": str(job.run_dir), "ok": summary is not None}
            if not entry["ok"]:
                entry["reason"] = job.reason or "no summary"
            if summary:
                entry["behaviour"] = summary.get("behaviour", {})
                entry["x_realtime"] = summary["timing"].get("x_realtime")
                rows.append(entry["behaviour"])
            runs.append({"condition": name, **entry})
        stats[name] = {key: _stats([r[key] for r in rows if key in r]) for key, _, _ in METRICS}
    return {"conditions": names, "stats": stats, "runs": runs, "tests": _tests(runs, names)}


def _values(runs: list[dict], name: str, key: str) -> list[float]:
    return [r["behaviour"][key] for r in runs
            if r["condition"] == name and r["ok"] and key in r.get("behaviour", {})]  # fmt: skip


def _tests(runs: list[dict], names: list[str]) -> list[dict]:
    """A permutation test of each metric: the first condition against each other one."""
    out = []
    for other in names[1:]:
        for key, _, _ in METRICS:
            a, b = _values(runs, names[0], key), _values(runs, other, key)
            if not a or not b:
                continue
            p, method = permutation_test(a, b)
            out.append({"metric": key, "a": names[0], "b": other, "n_a": len(a), "n_b": len(b),
                        "p_value": p, "method": method})  # fmt: skip
    return out


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
    failed = [r for r in result["runs"] if not r["ok"]]
    lines += ["", f"**Failed runs: {len(failed)}**" + (" (none)" if not failed else "")]
    if failed:
        lines += ["", "| condition | seed | reason |", "|---|---|---|"]
        lines += [f"| {r['condition']} | {r['seed']} | {r['reason']} |" for r in failed]
    lines += ["", "Each seed (— : the run failed, or has no such metric):", ""]
    lines += ["| condition | seed | " + " | ".join(label for _, label, _ in METRICS) + " |"]
    lines += ["|---|---|" + "---|" * len(METRICS)]
    for r in sorted(result["runs"], key=lambda r: (names.index(r["condition"]), r["seed"])):
        b = r.get("behaviour", {})
        cells = [fmt.format(b[key]) if key in b else "—" for key, _, fmt in METRICS]
        lines.append(f"| {r['condition']} | {r['seed']} | " + " | ".join(cells) + " |")
    if result.get("tests"):
        lines += ["", "Two-sided permutation test of the difference of means, each row on "
                  "its own (no correction for testing several metrics; with few runs the "
                  "smallest p a test can give is large: 3 vs 3 runs, 0.1):", ""]  # fmt: skip
        lines += ["| metric | conditions | n | p | method |", "|---|---|---|---|---|"]
        labels = {key: label for key, label, _ in METRICS}
        for t in result["tests"]:
            lines.append(f"| {labels[t['metric']]} | {t['a']} vs {t['b']} | "
                         f"{t['n_a']} vs {t['n_b']} | {t['p_value']:.4f} | "
                         f"{t['method']} |")  # fmt: skip
    return "\n".join(lines)


def _draw(queue: list[Job], names: list[str], out_dir: Path) -> list[Path]:
    seeds = sorted({j.seed for j in queue})
    fig = Figure(figsize=(2.2 * len(seeds) + 1.2, 2.4 * len(names) + 0.6), layout="constrained")
    axes = fig.subplots(len(names), len(seeds), squeeze=False)
    paths_of = {}  # (name, seed) -> (world, t_s, poses) of each run that ran
    for job in queue:
        if not job.reason and job.run_dir is not None:
            rec = read_run(job.run_dir)
            paths_of[job.name, job.seed] = (world_of(rec.manifest.get("config", {})),
                                            *rec.trajectory())  # fmt: skip
    # one colour scale for every run: the same colour is the same run time
    longest_s = max((float(t[-1]) for _, t, _ in paths_of.values() if t.size), default=1.0)
    shown = None
    for row, name in enumerate(names):
        for col, seed in enumerate(seeds):
            ax = axes[row][col]
            ax.set_axis_off()
            if (name, seed) not in paths_of:
                ax.set_title(f"{name} s{seed}: failed", fontsize=7)
                continue
            world, t_s, poses = paths_of[name, seed]
            if world is None:
                continue
            draw_world(world, ax)
            shown = ax.scatter(poses[:, 0], poses[:, 1], c=t_s, s=0.3, cmap="viridis",
                               vmin=0.0, vmax=longest_s)  # fmt: skip
            ax.set_title(f"{name} seed {seed}", fontsize=7)
    if shown is not None:
        fig.colorbar(shown, ax=axes, label="run time (s)", shrink=0.8)
    # on two lines where the figure is narrow (a few seeds), else it is cut at both sides
    sep = "\n" if len(seeds) < 4 else " "
    fig.suptitle(f"The robot's path in each run{sep}(arena to scale; colour: run time)")
    paths = []
    for suffix in (".png", ".svg"):
        path = out_dir / f"trajectories{suffix}"
        fig.savefig(path, dpi=130)
        paths.append(path)
    return paths
