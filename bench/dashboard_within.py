"""The live dashboard's cost to a lockstep closed loop, measured within one run.

``bench/closed_loop.py --only-dashboard`` compares whole runs without and with the
dashboard; on a shared two-vCPU host, runs of the same code a minute apart differ by 5-15 %,
so its pairs' ratios spread as widely as the cost it looks for. Here one long lockstep run
(``configs/closed_loop.toml``) steps throughout while a dashboard (``neuvision dashboard``,
as a user would start one beside a running hub, under ``SCHED_IDLE`` as by default) with a
page taking every frame (:class:`bench.closed_loop.PageClient`) comes and goes: windows of
``--window-s`` without and with it, side by side in ``--cycles`` cycles (A B, B A, ...). The
dashboard's start-up (its imports, the world it reads) is left out: a window with it starts
``--settle-s`` after its page got a first frame, a window without it as long after it ended.

Per window, from the run's record and ``/proc``: the steps completed a second (the body's
readings the hub took), the hub's CPU a step, the dashboard's share of a core, the page's
frames a second. The cost is ``1 - r`` for the median of the cycles' ratios ``r`` (with /
without), with a 90 % bootstrap interval, as in ``bench/closed_loop.py``.

    python bench/dashboard_within.py                    # 12 cycles of 2 x 8 s (~7 min)
    python bench/dashboard_within.py --cycles 20 --set dashboard.fps=10

The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.closed_loop import PageClient, paired_cost  # noqa: E402
from bench.host import StealMeter, child_popen, end_children_on_signal  # noqa: E402
from hub.bus import free_tcp_port  # noqa: E402
from hub.record import RECORD_FILE, iter_frames  # noqa: E402

# The run is asked for more run time than its cycles take at this many times real time (the
# closed loop goes 5-25x on these hosts); the bench stops it (``neuvision ctl stop``) when
# the cycles are done.
MAX_X_REALTIME = 40
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """User and system CPU seconds of process ``pid`` so far (all its threads)."""
    fields = _stat(pid)
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def minor_faults(pid: int) -> int:
    """Minor page faults of process ``pid`` so far (all its threads)."""
    return int(_stat(pid)[7])


def _stat(pid: int) -> list[str]:
    with open(f"/proc/{pid}/stat") as f:
        return f.read().rsplit(")", 1)[1].split()


class Window:
    """One stretch of the run: its wall-clock span and the CPU the hub (and the dashboard,
    when there is one) used over it."""

    def __init__(self, kind: str, hub_pid: int, dashboard_pid: int | None = None):
        self.kind, self.hub_pid, self.dashboard_pid = kind, hub_pid, dashboard_pid
        self.fps = None

    def __enter__(self) -> Window:
        self.t0_ns = time.time_ns()
        self.hub_cpu0 = cpu_s(self.hub_pid)
        self.hub_faults0 = minor_faults(self.hub_pid)
        self.dashboard_cpu0 = cpu_s(self.dashboard_pid) if self.dashboard_pid else 0.0
        self.page_cpu0 = time.process_time()  # this process: idle but for the page's thread
        return self

    def __exit__(self, *exc) -> None:
        self.t1_ns = time.time_ns()
        self.hub_cpu_s = cpu_s(self.hub_pid) - self.hub_cpu0
        self.hub_faults = minor_faults(self.hub_pid) - self.hub_faults0
        self.dashboard_cpu_s = (
            cpu_s(self.dashboard_pid) - self.dashboard_cpu0 if self.dashboard_pid else 0.0
        )
        self.page_cpu_s = time.process_time() - self.page_cpu0

    @property
    def seconds(self) -> float:
        return (self.t1_ns - self.t0_ns) / 1e9


def start_watcher(
    watcher: str, session: str, log: Path, extra: list[str]
) -> tuple[subprocess.Popen, int | None]:
    """The dashboard (and the port of its page), or a bare watcher of the hub's views."""
    if watcher == "bare":
        cmd, port = [sys.executable, "bench/view_watcher.py", session], None
    else:
        port = free_tcp_port()
        cmd = [sys.executable, "-m", "hub.cli", "dashboard", "--session", session]
        cmd += ["--port", str(port), *(a for item in extra for a in ("--set", item))]
    with open(log, "a") as out:
        proc = child_popen(cmd, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT)
    return proc, port


def stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def end_watched_run(session: str, run: subprocess.Popen, procs) -> None:
    """End the watchers ``procs`` (let go first if stopped), then the run (``ctl stop``),
    and wait for it: its analysis of a long record takes minutes."""
    for proc in procs:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGCONT)
            stop(proc)
    subprocess.run(
        [sys.executable, "-m", "hub.cli", "ctl", "stop", "--session", session],
        cwd=ROOT,
        capture_output=True,
    )
    try:
        run.wait(timeout=900)
    except subprocess.TimeoutExpired:
        run.terminate()
        run.wait()


def wait_for_steps(session: str, run: subprocess.Popen, timeout_s: float = 600.0) -> None:
    """Until the run steps (its endpoints built, their kernels compiled or loaded)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and run.poll() is None:
        status = subprocess.run(
            [sys.executable, "-m", "hub.cli", "ctl", "status", "--session", session],
            cwd=ROOT,
            capture_output=True,
            text=True,
        )
        if status.returncode == 0 and json.loads(status.stdout)["data"]["step"] > 0:
            print("  the run steps", flush=True)
            return
        time.sleep(1.0)
    raise SystemExit("the run did not start stepping")


def measure(args, tmp: Path) -> tuple[list[tuple[Window, Window]], Path]:
    session = f"bench-dashboard-within-{os.getpid()}"
    cmd = [sys.executable, "-m", "hub.cli", "run", "configs/closed_loop.toml", "--quiet"]
    run_s = args.cycles * (2 * (args.window_s + args.settle_s) + 20) * MAX_X_REALTIME
    cmd += ["--mode", "lockstep", "--duration-s", f"{run_s:.0f}", "--runs-dir", str(tmp / "runs")]
    cmd += ["--session", session]
    with open(tmp / "run.err", "w") as err:
        run = child_popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=err)
    pairs = []
    try:
        wait_for_steps(session, run)
        time.sleep(args.settle_s)
        for cycle in range(args.cycles):
            order = ("without", "with") if cycle % 2 == 0 else ("with", "without")
            done = {}
            for kind in order:
                if run.poll() is not None:
                    raise SystemExit(
                        f"the run ended early:\n{(tmp / 'run.err').read_text()[-2000:]}"
                    )
                if kind == "without":
                    with Window(kind, run.pid) as w:
                        time.sleep(args.window_s)
                else:
                    dash, port = start_watcher(args.watcher, session, tmp / "watcher.log", args.set)
                    page = PageClient(port) if port else None
                    deadline = time.monotonic() + 60
                    while page and page.frames == 0 and time.monotonic() < deadline:
                        time.sleep(0.05)
                    if page and page.frames == 0:
                        stop(dash)
                        raise SystemExit(f"no frame in 60 s; see {tmp / 'watcher.log'}")
                    time.sleep(args.settle_s + (0 if page else 3.0))  # bare: its imports
                    frames0, t0 = page.frames if page else 0, time.monotonic()
                    with Window(kind, run.pid, dash.pid) as w:
                        time.sleep(args.window_s)
                    if page:
                        w.fps = (page.frames - frames0) / (time.monotonic() - t0)
                        page.close()
                    stop(dash)
                    time.sleep(args.settle_s)  # the hub gathers for a second after the last ask
                done[kind] = w
            pairs.append((done["without"], done["with"]))
            print(f"  cycle {cycle + 1}/{args.cycles} measured", flush=True)
    finally:
        end_watched_run(session, run, ())
    (run_dir,) = (tmp / "runs").iterdir()
    return pairs, run_dir


def step_times_ns(run_dir: Path) -> list[int]:
    """When the hub took each of the body's readings (the steps completed, in wall time)."""
    return [
        f.t_wall_ns
        for f in iter_frames(run_dir / RECORD_FILE)
        if f.direction == "rx" and f.key.endswith("/sensors")
    ]


def steps_in(t_ns, w: Window) -> int:
    """Steps completed within ``w`` (from its start, up to but not at its end), given the
    sorted times ``t_ns`` at which steps completed."""
    import numpy as np

    return int(np.searchsorted(t_ns, w.t1_ns) - np.searchsorted(t_ns, w.t0_ns))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--cycles", type=int, default=12)
    ap.add_argument("--window-s", type=float, default=8.0)
    ap.add_argument("--settle-s", type=float, default=2.0)
    ap.add_argument("--watcher", choices=("dashboard", "bare"), default="dashboard",
                    help="bare: a process that takes the hub's views and nothing else")  # fmt: skip
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="config for the dashboard (e.g. dashboard.fps=10)")  # fmt: skip
    args = ap.parse_args()
    end_children_on_signal()
    import numpy as np

    with tempfile.TemporaryDirectory() as tmp, StealMeter() as steal:
        pairs, run_dir = measure(args, Path(tmp))
        t_ns = np.sort(np.asarray(step_times_ns(run_dir), np.int64))

    def page(row) -> str:
        if args.watcher != "dashboard":
            return ""
        return f", a page {row['fps']:.1f} frames/s and {row['page_share']:.1%} of a core"

    rows = []
    for i, (a, b) in enumerate(pairs, 1):
        na, nb = steps_in(t_ns, a), steps_in(t_ns, b)
        row = {
            "without_steps_per_s": na / a.seconds,
            "with_steps_per_s": nb / b.seconds,
            "without_hub_us": a.hub_cpu_s / max(na, 1) * 1e6,
            "with_hub_us": b.hub_cpu_s / max(nb, 1) * 1e6,
            "without_hub_faults": a.hub_faults / max(na, 1),
            "with_hub_faults": b.hub_faults / max(nb, 1),
            "dashboard_share": b.dashboard_cpu_s / b.seconds,
            "page_share": b.page_cpu_s / b.seconds,
            "fps": b.fps if b.fps is not None else float("nan"),
        }
        row["ratio"] = row["with_steps_per_s"] / row["without_steps_per_s"]
        rows.append(row)
        print(
            f"cycle {i:2d}: without {row['without_steps_per_s']:6.0f} steps/s (hub "
            f"{row['without_hub_us']:4.0f} us, {row['without_hub_faults']:.2f} faults a step), "
            f"with {row['with_steps_per_s']:6.0f} (hub {row['with_hub_us']:4.0f} us, "
            f"{row['with_hub_faults']:.2f} faults; the watcher {row['dashboard_share']:.1%} of a "
            f"core{page(row)}): ratio {row['ratio']:.3f}"
        )

    def med(key):
        return statistics.median(r[key] for r in rows)

    cost, lo, hi = paired_cost([r["ratio"] for r in rows])
    print(
        f"dashboard within one run, {len(rows)} cycles of 2 x {args.window_s:g} s: without "
        f"{med('without_steps_per_s'):.0f}, with {med('with_steps_per_s'):.0f} steps/s "
        f"(medians); cost {cost:+.1%} (90 % interval {lo:+.1%} to {hi:+.1%}); hub CPU a step "
        f"{med('without_hub_us'):.0f} -> {med('with_hub_us'):.0f} us, its minor page faults a "
        f"step {med('without_hub_faults'):.2f} -> {med('with_hub_faults'):.2f}; the watcher "
        f"({args.watcher}) {med('dashboard_share'):.1%} of a core"
        f"{page({k: med(k) for k in rows[0]})}; CPU steal {steal.share:.1%}"
    )
    print(
        json.dumps(
            {
                "dashboard_cost_share_within_run": round(cost, 4),
                "dashboard_cost_share_within_run_interval_90": [round(lo, 4), round(hi, 4)],
                "steps_per_s_without": round(med("without_steps_per_s"), 1),
                "steps_per_s_with": round(med("with_steps_per_s"), 1),
                "hub_cpu_us_per_step": {
                    "without": round(med("without_hub_us"), 1),
                    "with": round(med("with_hub_us"), 1),
                },
                "hub_minor_faults_per_step": {
                    "without": round(med("without_hub_faults"), 3),
                    "with": round(med("with_hub_faults"), 3),
                },
                "watcher_cpu_share": round(med("dashboard_share"), 4),
                "page_fps": round(med("fps"), 1) if args.watcher == "dashboard" else None,
                "page_cpu_share": (
                    round(med("page_share"), 4) if args.watcher == "dashboard" else None
                ),
                "cycles": len(rows),
                "window_s": args.window_s,
                "dashboard_set": args.set,
                "watcher": args.watcher,
                "steal_share": round(steal.share, 4),
            }
        )
    )


if __name__ == "__main__":
    main()
