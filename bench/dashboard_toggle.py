"""What the live dashboard's parts cost a lockstep closed loop, toggled in short windows.

On these shared two-vCPU hosts a lockstep closed loop's pace swings by ~16 % between 8 s
stretches, and not with the culture's activity (a 10-minute run's steps a second against
its spikes a step: correlation +0.12). ``bench/dashboard_within.py`` starts and ends a
dashboard for each window, so its windows last seconds and a dozen cycles leave an
interval of +-7 %. Here what is measured runs throughout and is switched on and off every
``--toggle-s``, in pairs of windows in alternating order (A B, B A, ...): hundreds of
pairs in a few minutes. ``--side`` says what is switched:

- ``hub``: a bare watcher of the hub's views (``bench/view_watcher.py --toggled``,
  under ``SCHED_IDLE`` as the dashboard unless ``--watcher normal``) asks for them or
  not. The hub gathers and builds its views only while someone asked within the last
  second, and sends them only when asked: the hub's side of the dashboard. Each window
  starts 0.3 s after the switch on; after the switch off the hub goes on gathering for a
  second, so ``--settle-after-switch-s 1.1`` measures it whole.
- ``page``: a dashboard (``neuvision dashboard --session S``, under ``SCHED_IDLE`` as by
  default) runs throughout; its page, a process of its own at normal priority as a
  browser would be, takes every frame or is stopped (``SIGSTOP``). A stopped page takes
  none, and the dashboard builds and sends none for it while its last one is unread: the
  frames' cost, the page's side included. The dashboard's taking of the views goes on.
- ``idle-cpu``: a process that only burns ``--cpu-share`` of a core (the dashboard's
  ~6 %) under ``SCHED_IDLE``, in 30 bursts a second, runs or is stopped: what CPU at
  idle priority alone costs the loop.
- ``frozen``: the dashboard and its page both run or are stopped (``SIGSTOP``). A frozen
  dashboard asks for no views, and the hub goes on building them for a second after its
  last question, so in half-second windows this is the cost of the dashboard's process,
  its page and the views' sending. (While views were published, a frozen dashboard held
  the hub up instead: docs/dashboard.md, "A frozen dashboard"; bench/dashboard_freeze.py.)

Per window, from the run's record and ``/proc``: the steps completed, the watcher's CPU.
The cost is ``1 - r``, ``r`` the pace of all windows with over that of all windows
without, with a 90 % bootstrap interval over the pairs; the median of the pairs' ratios
is printed too.

    python bench/dashboard_toggle.py                      # the hub's side, 300 pairs (~9 min)
    python bench/dashboard_toggle.py --side page --set dashboard.fps=20

The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.closed_loop import PageClient, paired_cost  # noqa: E402
from bench.dashboard_within import (  # noqa: E402
    MAX_X_REALTIME,
    cpu_s,
    end_watched_run,
    start_watcher,
    step_times_ns,
    wait_for_steps,
)
from bench.host import StealMeter, child_popen, end_children_on_signal  # noqa: E402


def page_main(port: int) -> None:
    """A page process: take every frame; print how many came so far when ready, at
    SIGUSR1, and at SIGTERM before it ends."""
    page = PageClient(port)
    done = threading.Event()

    def say(*_) -> None:
        print(json.dumps({"frames": page.frames, "bytes": page.bytes}), flush=True)

    signal.signal(signal.SIGUSR1, say)  # Python runs handlers in this thread, between waits
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    say()  # ready: the signals are taken from here on
    while not done.wait(0.1):
        pass
    say()  # and end: the page's thread is a daemon, left in its read of the next frame


def pooled_cost(steps, spans, resamples: int = 5000) -> tuple[float, float, float]:
    """The cost ``1 - r``, ``r`` the pace of all windows with over that of all windows
    without (``steps`` and ``spans``: float[pairs, 2], without then with), and a 90 %
    interval of it: a percentile bootstrap over the pairs (fixed seed). Pooled rather
    than the median of the pairs' ratios: a half-second window's pace is noisy, and its
    ratio's distribution skewed."""
    import numpy as np

    steps, spans = np.asarray(steps, float), np.asarray(spans, float)

    def cost(i) -> np.ndarray:
        pace = steps[i].sum(axis=-2) / spans[i].sum(axis=-2)
        return 1 - pace[..., 1] / pace[..., 0]

    rng = np.random.default_rng(0)
    lo, hi = np.quantile(cost(rng.integers(0, len(steps), (resamples, len(steps)))), [0.05, 0.95])
    return float(cost(np.arange(len(steps)))), float(lo), float(hi)


class PageSide:
    """The dashboard runs throughout; its page (a process) is stopped (``SIGSTOP``) or let
    go on. A stopped page takes no frame, and the dashboard builds and sends none for it
    while it has not taken the last one (its socket full): what the frames cost, the
    page's side of them included. The dashboard's taking of the views goes on."""

    lag_s = 0.0  # a stopped process takes no CPU from the moment it is stopped

    def __init__(self, session: str, tmp: Path, sets: list[str]):
        self.dash, port = start_watcher("dashboard", session, tmp / "dashboard.log", sets)
        self.page = child_popen(
            [sys.executable, __file__, "--page-port", str(port)],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            text=True,
        )
        self.procs = [self.dash, self.page]
        self.frozen = [self.page]
        self.page.stdout.readline()  # ready for SIGUSR1
        self.frames0 = 0

    def started(self) -> None:
        os.kill(self.page.pid, signal.SIGUSR1)
        self.frames0 = json.loads(self.page.stdout.readline())["frames"]

    def on(self, on: bool) -> None:
        for proc in self.frozen:
            os.kill(proc.pid, signal.SIGCONT if on else signal.SIGSTOP)

    def frames(self) -> int | None:
        """The frames the page took since :meth:`started` (it ends)."""
        os.kill(self.page.pid, signal.SIGCONT)
        self.page.terminate()
        out, _ = self.page.communicate(timeout=15)
        lines = out.strip().splitlines()
        if not lines:  # the page ended without its last word (killed)
            print(f"  the page said nothing at its end (exit status {self.page.returncode})")
            return None
        return json.loads(lines[-1])["frames"] - self.frames0


class FrozenSide(PageSide):
    """The dashboard and its page both stopped (``SIGSTOP``, as a debugger, a swap storm or
    a suspended machine would) or let go on. A frozen dashboard asks for no views; the hub
    builds them for a second after the last question: in half-second windows, the cost
    of the dashboard's process, its page and the answers."""

    def __init__(self, session: str, tmp: Path, sets: list[str]):
        super().__init__(session, tmp, sets)
        self.frozen = [self.dash, self.page]


class IdleCpuSide:
    """A process that only burns CPU under ``SCHED_IDLE``, ``--cpu-share`` of a core in 30
    bursts a second (as the dashboard's pump), stopped (``SIGSTOP``) or let go on: what
    CPU at idle priority alone costs the loop, without sockets or memory traffic."""

    lag_s = 0.0

    def __init__(self, session: str, tmp: Path, sets: list[str], cpu_share: float):
        cmd = [sys.executable, __file__, "--burn", str(cpu_share)]
        self.dash = child_popen(cmd, cwd=ROOT)
        self.procs = [self.dash]

    def started(self) -> None:
        pass

    def on(self, on: bool) -> None:
        os.kill(self.dash.pid, signal.SIGCONT if on else signal.SIGSTOP)

    def frames(self) -> None:
        return None


def burn_main(cpu_share: float, hz: float = 30.0) -> None:
    """Burn ``cpu_share`` of a core in ``hz`` bursts a second under ``SCHED_IDLE``."""
    from hub.scheduling import yield_cpu

    yield_cpu()
    burst_s, next_s = cpu_share / hz, time.monotonic()
    while True:
        end = time.thread_time() + burst_s
        while time.thread_time() < end:
            sum(range(200))
        next_s = max(next_s + 1 / hz, time.monotonic())  # after a stop: no catching up
        time.sleep(next_s - time.monotonic())


class HubSide:
    """A bare watcher of the hub's views (``bench/view_watcher.py --toggled``) that asks for
    them (``SIGUSR1``) or not (``SIGUSR2``): the hub gathers and builds its views while
    someone asked within the last second, and sends them only when asked."""

    lag_s = 0.3  # the hub's next look

    def __init__(self, session: str, tmp: Path, sets: list[str], idle: bool = True):
        cmd = [sys.executable, "bench/view_watcher.py", session, "--toggled"]
        cmd += ["--idle"] if idle else []
        with open(tmp / "watcher.log", "w") as out:
            self.dash = child_popen(cmd, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT)
        self.procs = [self.dash]

    def started(self) -> None:
        pass

    def on(self, on: bool) -> None:
        os.kill(self.dash.pid, signal.SIGUSR1 if on else signal.SIGUSR2)

    def frames(self) -> int | None:
        return None


SIDES = {"hub": HubSide, "page": PageSide, "frozen": FrozenSide, "idle-cpu": IdleCpuSide}


def measure(args, tmp: Path) -> tuple[list[dict], Path, float | None]:
    """Pairs of windows ``{"with": (t0_ns, t1_ns, the watcher's CPU s), "without": ...}``,
    the run's folder, and the page's frames a second while let run (None: no page)."""
    session = f"bench-dashboard-toggle-{os.getpid()}"
    lag_s = max(SIDES[args.side].lag_s, args.settle_after_switch_s or 0.0)
    windows_s = 2 * args.pairs * (args.toggle_s + lag_s)
    run_s = (windows_s + 120) * MAX_X_REALTIME
    cmd = [sys.executable, "-m", "hub.cli", "run", "configs/closed_loop.toml", "--quiet"]
    cmd += ["--mode", "lockstep", "--duration-s", f"{run_s:.0f}", "--runs-dir", str(tmp / "runs")]
    cmd += ["--session", session]
    with open(tmp / "run.err", "w") as err:
        run = child_popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=err)
    pairs, fps, side = [], None, None
    try:
        wait_for_steps(session, run)
        extra = {"idle-cpu": (args.cpu_share,), "hub": (args.watcher == "idle",)}.get(args.side, ())
        side = SIDES[args.side](session, tmp, args.set, *extra)
        time.sleep(args.settle_s)  # the watcher's imports, its scene, the page's first frames
        side.started()
        lag_s = side.lag_s if args.settle_after_switch_s is None else args.settle_after_switch_s
        with_s = 0.0
        for i in range(args.pairs):
            order = ("without", "with") if i % 2 == 0 else ("with", "without")
            pair = {}
            for kind in order:
                side.on(kind == "with")
                time.sleep(lag_s)
                t0, c0 = time.time_ns(), cpu_s(side.dash.pid)
                time.sleep(args.toggle_s)
                pair[kind] = (t0, time.time_ns(), cpu_s(side.dash.pid) - c0)
                if kind == "with":
                    with_s += (pair[kind][1] - t0) / 1e9
            pairs.append(pair)
            if (i + 1) % 50 == 0 or i + 1 == args.pairs:
                print(f"  {i + 1}/{args.pairs} pairs measured", flush=True)
            if any(proc.poll() is not None for proc in side.procs):
                raise SystemExit(f"the watcher ended early (see {tmp}/*.log)")
            if run.poll() is not None:
                raise SystemExit(f"the run ended early:\n{(tmp / 'run.err').read_text()[-2000:]}")
        frames = side.frames()
        fps = frames / with_s if frames is not None else None
    finally:
        end_watched_run(session, run, side.procs if side else ())
    (run_dir,) = (tmp / "runs").iterdir()
    return pairs, run_dir, fps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--pairs", type=int, default=300)
    ap.add_argument("--side", choices=tuple(SIDES), default="hub",
                    help="hub: a bare watcher asks for the hub's views or not; page: a "
                    "dashboard's page takes frames or is stopped; frozen: the dashboard and "
                    "its page run or are stopped")  # fmt: skip
    ap.add_argument("--toggle-s", type=float, default=0.5, help="each window's length")
    ap.add_argument("--settle-after-switch-s", type=float, default=None,
                    help="left out after each switch (default: the side's own: 0.3 s for the "
                    "hub's next look, else 0)")  # fmt: skip
    ap.add_argument("--settle-s", type=float, default=15.0,
                    help="after the dashboard starts, before the first window")  # fmt: skip
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="config for the dashboard (e.g. dashboard.fps=20)")  # fmt: skip
    ap.add_argument("--cpu-share", type=float, default=0.06,
                    help="idle-cpu: the share of a core burnt (the dashboard: ~0.06)")  # fmt: skip
    ap.add_argument("--watcher", choices=("idle", "normal"), default="idle",
                    help="hub: the watcher under SCHED_IDLE as the dashboard (default), or "
                    "the ordinary scheduler")  # fmt: skip
    ap.add_argument("--page-port", type=int, help=argparse.SUPPRESS)  # the page's process
    ap.add_argument("--burn", type=float, help=argparse.SUPPRESS)  # idle-cpu's process
    args = ap.parse_args()
    if args.page_port is not None:
        return page_main(args.page_port)
    if args.burn is not None:
        return burn_main(args.burn)
    end_children_on_signal()
    import numpy as np

    with tempfile.TemporaryDirectory() as tmp, StealMeter() as steal:
        pairs, run_dir, fps = measure(args, Path(tmp))
        print("  reading the record", flush=True)
        t_ns = np.sort(np.asarray(step_times_ns(run_dir), np.int64))

    def steps_in(window) -> int:
        t0, t1, _ = window
        return int(np.searchsorted(t_ns, t1) - np.searchsorted(t_ns, t0))

    steps = np.array([[steps_in(p[k]) for k in ("without", "with")] for p in pairs], float)
    spans = np.array([[(p[k][1] - p[k][0]) / 1e9 for k in ("without", "with")] for p in pairs])
    cost, lo, hi = pooled_cost(steps, spans)
    without, with_ = steps.sum(axis=0) / spans.sum(axis=0)
    median_cost, _, _ = paired_cost(list(steps[:, 1] / spans[:, 1] / (steps[:, 0] / spans[:, 0])))
    share = {
        kind: sum(p[kind][2] for p in pairs) / sum((p[kind][1] - p[kind][0]) / 1e9 for p in pairs)
        for kind in ("without", "with")
    }
    what = {
        "hub": f"the hub's views (a bare watcher, {args.watcher} priority, asking or not)",
        "page": "the dashboard's page (taking frames or stopped)",
        "frozen": "the dashboard and its page (running or frozen)",
        "idle-cpu": f"{args.cpu_share:.0%} of a core burnt under SCHED_IDLE (or stopped)",
    }[args.side]
    page = f", its page ~{fps:.0f} frames/s" if fps is not None else ""
    settle_s = args.settle_after_switch_s
    settle_s = SIDES[args.side].lag_s if settle_s is None else settle_s
    print(
        f"{what} toggled, {len(pairs)} pairs of {args.toggle_s:g} s windows: "
        f"without {without:.0f}, with {with_:.0f} steps/s (all windows of each kind); cost "
        f"{cost:+.1%} (90 % interval {lo:+.1%} to {hi:+.1%}; from the median of the pairs' "
        f"ratios {median_cost:+.1%}); the watcher {share['without']:.1%} of a core without, "
        f"{share['with']:.1%} with"
        f"{page}; CPU steal {steal.share:.1%}"
    )
    print(
        json.dumps(
            {
                "dashboard_cost_share_toggled": round(cost, 4),
                "dashboard_cost_share_toggled_interval_90": [round(lo, 4), round(hi, 4)],
                "dashboard_cost_share_toggled_median_pair": round(median_cost, 4),
                "steps_per_s_without": round(without, 1),
                "steps_per_s_with": round(with_, 1),
                "watcher_cpu_share": {k: round(v, 4) for k, v in share.items()},
                "page_fps": round(fps, 1) if fps is not None else None,
                "side": args.side,
                "watcher_priority": args.watcher if args.side == "hub" else None,
                "pairs": len(pairs),
                "toggle_s": args.toggle_s,
                "settle_after_switch_s": settle_s,
                "dashboard_set": args.set,
                "steal_share": round(steal.share, 4),
            }
        )
    )


if __name__ == "__main__":
    main()
