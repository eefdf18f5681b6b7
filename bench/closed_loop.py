"""Benchmark of the full closed loop: hub, 1024-neuron culture and arena, three processes.

1. Lockstep speed of configs/closed_loop.toml (dt 0.1 ms, 10 ms period) as simulated/wall
   time, and where the wall time goes: the culture's and the arena's time inside their
   step (measured by the endpoints themselves), and the hub's busy time (wall time minus
   the time the hub spent waiting for replies), and the CPU time per step of each
   process: on a machine with few cores, the loop is bound by their sum.
2. A realtime run at a 10 ms period: late steps and the lateness of step starts, and the
   host's stalls seen meanwhile (``tests/stall_witness.py``): how many missed replies no
   stall explains.
3. The cost of the live dashboard: lockstep runs without and with ``--dashboard`` (a page
   connected by websocket, taking every frame), interleaved A/B/B/A in this session;
   ``x_realtime_lockstep_with_dashboard`` against ``x_realtime_lockstep_ab`` (medians).
   The page also checks that the dashboard kept showing the run: the longest its step stood
   still (``dashboard_page_still_s_max``), and the runs whose page froze before the end
   (``dashboard_pages_frozen``; a frozen dashboard costs the loop less, and its run would
   pass for a cheap one). With ``--dashboard-mode realtime`` the runs are realtime
   instead, at the paper's 10 ms period, and what is compared is what watching costs a
   realtime run: its late steps, the lateness of its step starts and its late and missing
   replies (``dashboard_rt_*``).

    python bench/closed_loop.py                 # 60 s lockstep + 60 s realtime + 3 A/B pairs
    python bench/closed_loop.py --seconds 20
    python bench/closed_loop.py --realtime-priority 0   # realtime under the ordinary scheduler
    python bench/closed_loop.py --only-dashboard --dashboard-pairs 4
    python bench/closed_loop.py --only-dashboard --dashboard-mode realtime --seconds 30

The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.host import StealMeter, child_run, end_children_on_signal  # noqa: E402
from hub.bus import free_tcp_port  # noqa: E402
from hub.record import read_run  # noqa: E402
from tests.stall_witness import StallWitness  # noqa: E402


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


class PageClient:
    """A page on the dashboard's websocket that takes every frame (as a browser's would
    arrive) without drawing it: the dashboard's own cost, not a browser's (which may run
    on another machine)."""

    def __init__(self, port: int):
        self.url = f"ws://127.0.0.1:{port}/ws"
        self.frames = 0
        self.bytes = 0
        self.first = self.last = 0.0  # when the first and the last frame came
        # The step the frames show: the newest, when it last moved, and the longest it
        # stood still between two moves (a page frozen while the run went on; the frame's
        # JSON is read up to its step only, to keep this page's cost what it was)
        self.step = -1
        self.moved_at = 0.0
        self.still_s_max = 0.0
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from websockets.sync.client import connect

        while not self._done.is_set():
            try:
                with connect(self.url, open_timeout=1.0) as ws:
                    for text in ws:
                        self.last = time.monotonic()
                        self.first = self.first or self.last
                        self.frames += 1
                        self.bytes += len(text)
                        self._saw(_frame_step(text), self.last)
            except OSError:
                self._done.wait(0.2)  # not serving yet
            except Exception:  # the run ended: its dashboard with it
                return

    def _saw(self, step: int | None, now: float) -> None:
        if step is None or step <= self.step:
            return
        if self.step >= 0:
            self.still_s_max = max(self.still_s_max, now - self.moved_at)
        self.step, self.moved_at = step, now

    def close(self) -> None:
        self._done.set()
        self._thread.join(timeout=5)

    @property
    def fps(self) -> float:
        span = self.last - self.first
        return (self.frames - 1) / span if span > 0 else 0.0


_FRAME_STEP = re.compile(r'\{"type":"frame".{0,200}?"step":(-?\d+)')
# A page whose last step is behind its run's last by more than this share of the run's
# steps froze (the hub waits for a live display's last view before it ends)
FROZEN_SHARE = 0.01


def _frame_step(text: str) -> int | None:
    """The step a page's frame shows (None for other messages): read from its head."""
    found = _FRAME_STEP.match(text)
    return int(found.group(1)) if found else None


def dashboard_ab(seconds: float, pairs: int, sets: list[str] = (), mode: str = "lockstep") -> dict:
    """Runs without (A) and with (B) the dashboard, interleaved A B B A ...; each B run
    with a page connected. Besides the speed, the hub's CPU time per step (the lockstep
    loop's bound on two cores), the dashboard process's own CPU share (its log), and the
    CPU per step of the loop's processes, the dashboard's and the page's.
    ``sets``: more ``--set KEY=VALUE`` for the B runs (``dashboard.yield_cpu=false``).
    ``mode``: ``lockstep`` (the cost is the speed lost) or ``realtime`` (the cost is in
    late steps and replies: :func:`_realtime_figures`)."""
    x = {"A": [], "B": []}
    hub_us = {"A": [], "B": []}
    # CPU per step: the loop's processes (hub, endpoints, burst observer), and with B the
    # dashboard's process (from its log) and the page (this process, idle but for it)
    cpu_us = {"A": {"loop": []}, "B": {"loop": [], "dashboard": [], "page": []}}
    fps, dash_cpu, dash_cpu_stepping = [], [], []
    still_s, behind = [], []  # the page's longest stand-still; steps it never showed
    frozen = 0  # pages that stood still before their run's end
    timings = {"A": [], "B": []}  # each run's timing and counts (realtime: lateness)
    order = [("A", "B") if i % 2 == 0 else ("B", "A") for i in range(pairs)]
    with StealMeter() as steal:
        for pair in order:
            for which in pair:
                extra, page = [], None
                if which == "B":
                    port = free_tcp_port()
                    extra = ["--dashboard", "--set", f"dashboard.port={port}"]
                    extra += [a for item in sets for a in ("--set", item)]
                    page = PageClient(port)
                page_cpu = time.process_time()
                with tempfile.TemporaryDirectory() as tmp:
                    m, _ = run(mode, seconds, Path(tmp) / "runs", *extra)
                    log = next(Path(tmp).glob("runs/*/dashboard.log"), None)
                    text = log.read_text() if log else ""
                    share = _dashboard_cpu(text)
                    stepping = _dashboard_cpu(text, since_first_step=True)
                page_cpu = time.process_time() - page_cpu
                steps = max(m["timing"]["steps"], 1)
                cpu_us[which]["loop"].append(_loop_cpu_s(m) / steps * 1e6)
                if page is not None:
                    page.close()
                    cpu_us["B"]["page"].append(page_cpu / steps * 1e6)
                    dashboard_s = _dashboard_cpu_s(text)
                    if dashboard_s is not None:
                        cpu_us["B"]["dashboard"].append(dashboard_s / steps * 1e6)
                    fps.append(page.fps)
                    still_s.append(page.still_s_max)
                    behind.append(steps - 1 - page.step)
                    frozen += behind[-1] > FROZEN_SHARE * steps
                    if share is not None:
                        dash_cpu.append(share)
                    if stepping is not None:
                        dash_cpu_stepping.append(stepping)
                t = m["timing"]
                timings[which].append((t, m["counts"]))
                x[which].append(t["x_realtime"])
                hub_us[which].append(t["hub_cpu_s"] / t["steps"] * 1e6)
                late = ""
                if mode == "realtime":
                    late = (
                        f", {t['late_steps']} late steps, lateness p99 "
                        f"{t['lateness_ms_p99']:.3f} ms, max {t['lateness_ms_max']:.2f} ms"
                    )
                print(
                    f"  {which}: {t['x_realtime']:.2f}x real time, hub "
                    f"{hub_us[which][-1]:.0f} us CPU per step{late}",
                    flush=True,
                )
    a, b = statistics.median(x["A"]), statistics.median(x["B"])
    ha, hb = statistics.median(hub_us["A"]), statistics.median(hub_us["B"])
    ratios = [xb / xa for xa, xb in zip(x["A"], x["B"], strict=True)]
    paired, lo, hi = paired_cost(ratios)
    cpu = {k: {part: _median(v) for part, v in parts.items()} for k, parts in cpu_us.items()}
    if mode == "realtime":
        out = _realtime_figures(timings, fps, still_s, frozen, steal.share, seconds)
        print(
            f"hub CPU per step {ha:.0f} us without, {hb:.0f} us with; the dashboard's process "
            f"{_median(dash_cpu_stepping):.1%} of a core from the first step it showed"
        )
        out["dashboard_hub_cpu_us_per_step"] = {"A": round(ha, 1), "B": round(hb, 1)}
        out["dashboard_process_cpu_share_stepping"] = round(_median(dash_cpu_stepping), 4)
        return out
    print(
        f"dashboard A/B, {pairs} pairs of {seconds:g} s lockstep: without {a:.2f}x, with "
        f"{b:.2f}x real time (medians; cost {1 - b / a:+.1%}; pairs' ratios "
        f"{min(ratios):.2f}-{max(ratios):.2f}, their median a cost of {paired:+.1%}, 90 % "
        f"interval {lo:+.1%} to {hi:+.1%}); hub CPU per step {ha:.0f} vs {hb:.0f} us; "
        f"a page got {statistics.median(fps):.1f} frames/s; the dashboard's process used "
        f"{statistics.median(dash_cpu) if dash_cpu else float('nan'):.1%} of a core over its life, "
        f"{statistics.median(dash_cpu_stepping) if dash_cpu_stepping else float('nan'):.1%} "
        f"from the first step it showed; CPU steal {steal.share:.1%}"
    )
    print(
        f"the page: longest stand-still of its step {max(still_s):.2f} s; its last step "
        f"behind the run's by {min(behind)}-{max(behind)} steps; {frozen} of {len(behind)} "
        "pages frozen before their run's end"
    )
    print(
        f"CPU per step (medians): the loop's processes {cpu['A']['loop']:.0f} us without, "
        f"{cpu['B']['loop']:.0f} us with the dashboard, whose process took "
        f"{cpu['B']['dashboard']:.0f} us and the page {cpu['B']['page']:.0f} us"
    )
    return {
        "x_realtime_lockstep_with_dashboard": round(b, 2),
        "x_realtime_lockstep_ab": round(a, 2),
        "dashboard_cost_share": round(1 - b / a, 4),
        "dashboard_cost_share_paired": round(paired, 4),
        "dashboard_cost_share_interval_90": [round(lo, 4), round(hi, 4)],
        "dashboard_ab_runs": {k: [round(v, 2) for v in vs] for k, vs in x.items()},
        "dashboard_hub_cpu_us_per_step": {"A": round(ha, 1), "B": round(hb, 1)},
        "dashboard_page_fps": round(statistics.median(fps), 1),
        "dashboard_page_still_s_max": round(max(still_s), 3),
        "dashboard_page_steps_behind_at_end": behind,
        "dashboard_pages_frozen": frozen,
        "dashboard_process_cpu_share": round(statistics.median(dash_cpu), 4) if dash_cpu else None,
        "dashboard_process_cpu_share_stepping": (
            round(statistics.median(dash_cpu_stepping), 4) if dash_cpu_stepping else None
        ),
        "dashboard_ab_steal_share": round(steal.share, 4),
        "dashboard_cpu_us_per_step": {
            k: {part: round(v, 1) for part, v in parts.items()} for k, parts in cpu.items()
        },
    }


def _realtime_figures(
    timings: dict, fps: list, still_s: list, frozen: int, steal: float, seconds: float
) -> dict:
    """What watching cost realtime runs: per side, each run's late steps, the lateness of
    its step starts (p99, max) and its late and missing replies (all roles)."""
    side = {}
    for which, runs in timings.items():
        side[which] = {
            "late_steps": [t["late_steps"] for t, _ in runs],
            "p99_lateness_ms": [round(t["lateness_ms_p99"], 4) for t, _ in runs],
            "max_lateness_ms": [round(t["lateness_ms_max"], 3) for t, _ in runs],
            "late_replies": [sum(c["late"].values()) for _, c in runs],
            "missing_replies": [sum(c["missing"].values()) for _, c in runs],
        }
    for which, name in (("A", "without"), ("B", "with")):
        f = side[which]
        print(
            f"realtime 10 ms, {len(f['late_steps'])} runs of {seconds:g} s {name} the "
            f"dashboard: late steps {f['late_steps']}, lateness p99 "
            f"{_median(f['p99_lateness_ms']):.3f} ms (median of runs), max "
            f"{max(f['max_lateness_ms']):.2f} ms; late replies {f['late_replies']}, missing "
            f"{f['missing_replies']}"
        )
    print(
        f"the page got {statistics.median(fps):.1f} frames/s; longest stand-still of its step "
        f"{max(still_s):.2f} s; {frozen} of {len(still_s)} pages frozen; CPU steal {steal:.1%}"
    )
    return {
        "dashboard_rt_runs": side,
        "dashboard_rt_late_steps": {k: sum(v["late_steps"]) for k, v in side.items()},
        "dashboard_rt_p99_lateness_ms": {
            k: round(_median(v["p99_lateness_ms"]), 4) for k, v in side.items()
        },
        "dashboard_rt_max_lateness_ms": {k: max(v["max_lateness_ms"]) for k, v in side.items()},
        "dashboard_page_fps": round(statistics.median(fps), 1),
        "dashboard_page_still_s_max": round(max(still_s), 3),
        "dashboard_pages_frozen": frozen,
        "dashboard_ab_steal_share": round(steal, 4),
    }


def _median(values: list[float]) -> float:
    return statistics.median(values) if values else float("nan")


def _loop_cpu_s(manifest: dict) -> float:
    """CPU seconds of the loop's processes over a run: the hub, its endpoints and the burst
    observer (as the run's manifest says)."""
    endpoints = manifest.get("endpoints") or {}
    observer_s = (manifest.get("counts") or {}).get("online_observer_cpu_s") or 0.0
    return (
        manifest["timing"]["hub_cpu_s"]
        + sum(e.get("cpu_s") or 0.0 for e in endpoints.values())
        + observer_s
    )


def _dashboard_cpu_s(log: str) -> float | None:
    """The dashboard process's CPU seconds from the first step it showed (its start-up left
    out; the hub holds its first step until the dashboard watches), from its log."""
    found = _STEPPING_CPU.search(log)
    return float(found.group(1)) if found else None


def paired_cost(ratios: list[float], resamples: int = 5000) -> tuple[float, float, float]:
    """The cost ``1 - r`` from the median of the pairs' speed ratios ``r`` (with/without,
    each pair run side by side, so a drift of the host's speed between pairs cancels), and
    a 90 % interval of it: a percentile bootstrap over the pairs (fixed seed)."""
    import numpy as np

    r = np.asarray(ratios, float)
    rng = np.random.default_rng(0)
    medians = np.median(r[rng.integers(0, r.size, (resamples, r.size))], axis=1)
    lo, hi = np.quantile(medians, [0.05, 0.95])
    return 1 - float(np.median(r)), 1 - float(hi), 1 - float(lo)


# The dashboard's log lines at its end (dashboard/server.py): its CPU over its life, and from
# the first step it showed (its cost while the run stepped): CPU seconds, then share in %
_LIFE_CPU = re.compile(r"used ([\d.]+) s of CPU \(([\d.]+) %")
_STEPPING_CPU = re.compile(r"first step shown: ([\d.]+) s of CPU in [\d.]+ s \(([\d.]+) %")


def _dashboard_cpu(log: str, since_first_step: bool = False) -> float | None:
    """The dashboard process's CPU share, from a line it logs when it ends: over its life,
    or from the first step it showed (its cost while the run stepped)."""
    found = (_STEPPING_CPU if since_first_step else _LIFE_CPU).search(log)
    return float(found.group(2)) / 100 if found else None


def _scheduling(s: dict) -> str:
    """``fifo 10`` or ``normal``: the hub's threads during a realtime run."""
    return f"fifo {s['priority']}" if s["policy"] == "fifo" else "normal"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per run")
    parser.add_argument(
        "--realtime-priority", type=int, help="loop.realtime_priority of the realtime run"
    )
    parser.add_argument(
        "--dashboard-pairs", type=int, default=3, help="A/B pairs for the dashboard's cost"
    )
    parser.add_argument(
        "--only-dashboard", action="store_true", help="only the dashboard's A/B runs"
    )
    parser.add_argument(
        "--dashboard-set", action="append", default=[], metavar="KEY=VALUE",
        help="a --set for the runs with the dashboard (e.g. dashboard.yield_cpu=false)",
    )  # fmt: skip
    parser.add_argument(
        "--dashboard-mode", choices=("lockstep", "realtime"), default="lockstep",
        help="the A/B's runs: lockstep (the speed lost) or realtime (late steps and replies)",
    )  # fmt: skip
    args = parser.parse_args()
    end_children_on_signal()
    out = {}
    if args.only_dashboard:
        out.update(
            dashboard_ab(
                args.seconds, args.dashboard_pairs, args.dashboard_set, args.dashboard_mode
            )
        )
        out["dashboard_sets"] = args.dashboard_set
        out["seconds"] = args.seconds
        print(json.dumps(out))
        return
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
    # whether idle CPUs were kept from sleeping (loop.keep_cpus_awake): it moves the figures
    out["cpus_awake"] = t["cpus_awake"]["held"]
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
        with StallWitness() as witness:
            m, steal = run("realtime", args.seconds, Path(tmp) / "realtime", *extra)
        (run_dir,) = [p for p in (Path(tmp) / "realtime").iterdir() if p.is_dir()]
        stalls = witness.figures(read_run(run_dir))
    t = m["timing"]
    sched = t["scheduling"]
    print(
        f"realtime 10 ms ({_scheduling(sched)}), {t['steps']} steps: late steps "
        f"{t['late_steps']}, lateness median "
        f"{t['lateness_ms_median']:.3f} ms, p99 {t['lateness_ms_p99']:.3f} ms, "
        f"max {t['lateness_ms_max']:.3f} ms; missing {m['counts']['missing']}; "
        f"CPU steal {steal:.1%}; {witness.summary()}, replies missed "
        f"{stalls['missed_replies']}, of which no stall explains "
        f"{stalls['missed_replies_unexplained']}"
    )
    out["rt10_steal_share"] = round(steal, 4)
    out.update({f"rt10_{k}": v for k, v in stalls.items()})
    out["rt10_late_steps"] = t["late_steps"]
    out["rt10_p99_lateness_ms"] = round(t["lateness_ms_p99"], 4)
    out["rt10_median_lateness_ms"] = round(t["lateness_ms_median"], 4)
    out["rt10_max_lateness_ms"] = round(t["lateness_ms_max"], 3)
    out["rt_scheduling"] = _scheduling(sched)
    if args.dashboard_pairs > 0:
        out.update(
            dashboard_ab(
                args.seconds, args.dashboard_pairs, args.dashboard_set, args.dashboard_mode
            )
        )
        out["dashboard_sets"] = args.dashboard_set
    out["seconds"] = args.seconds
    print(json.dumps(out))


if __name__ == "__main__":
    main()
