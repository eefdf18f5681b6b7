"""Does a frozen watcher of the hub's views hold the loop up? Freeze it and look at the steps.

A watcher that stops reading — stopped (``SIGSTOP``, a debugger), swapped out, or on a link
slower than the views — once held the loop up: while the hub published its views, the
watcher's socket filled within about a second, and Zenoh then held the hub's next put
until the watcher read again (docs/dashboard.md, "A frozen dashboard"). Here a lockstep
closed loop runs with a watcher (``--watcher bare``: ``bench/view_watcher.py``; or
``dashboard``: ``neuvision dashboard`` and a page taking its frames; or ``observer``: the
run's own burst observer, which asks the hub for its spikes as a watcher asks for views),
which is frozen for ``--freeze-s`` and let run as long, ``--freezes`` times. From the
run's record: the steps made in each freeze and after it, and the longest gap between two
steps in each cycle, with where it began and ended (ms from the freeze).

    python bench/dashboard_freeze.py                      # 8 freezes of 1.5 s, bare watcher
    python bench/dashboard_freeze.py --watcher dashboard --freezes 12
    python bench/dashboard_freeze.py --watcher observer

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
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.dashboard_within import (  # noqa: E402
    end_watched_run,
    start_watcher,
    step_times_ns,
    wait_for_steps,
)
from bench.host import StealMeter, child_popen, end_children_on_signal  # noqa: E402

MAX_X_REALTIME = 60  # the run's length: the freezes at up to this pace, and margin


def longest_gaps(t_ns, cycles) -> list[dict]:
    """For each cycle ``(t0, t1, t2)`` (frozen over ``[t0, t1)``, running over ``[t1,
    t2)``, ns) and the sorted times ``t_ns`` at which steps completed: the steps in each
    half and the longest gap between two steps within the cycle (ms, and where it began
    and ended in ms from ``t0``)."""
    import numpy as np

    t_ns = np.asarray(t_ns, np.int64)
    out = []
    for t0, t1, t2 in cycles:
        i0, i1, i2 = np.searchsorted(t_ns, [t0, t1, t2])
        inside = t_ns[i0:i2]
        row = {"steps_frozen": int(i1 - i0), "steps_running": int(i2 - i1)}
        if inside.size > 1:
            k = int(np.argmax(np.diff(inside)))
            row.update(
                gap_ms=round(float(inside[k + 1] - inside[k]) / 1e6, 1),
                gap_from_ms=round(float(inside[k] - t0) / 1e6),
                gap_to_ms=round(float(inside[k + 1] - t0) / 1e6),
            )
        out.append(row)
    return out


def burst_observer_of(session: str) -> int:
    """The process id of the burst observer the hub of ``session`` started."""
    for entry in os.listdir("/proc"):
        try:
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                args = f.read().split(b"\0")
        except (OSError, ValueError):
            continue
        if b"observe" in args and b"bursts" in args and any(session.encode() in a for a in args):
            return int(entry)
    raise SystemExit(f"no burst observer of session {session!r}")


def _continue(pid: int) -> None:
    """SIGCONT, if it is still there (an observer the hub let go may have ended)."""
    try:
        os.kill(pid, signal.SIGCONT)
    except ProcessLookupError:
        pass


def measure(args, tmp: Path) -> tuple[list[tuple[int, int, int]], Path]:
    session = f"bench-dashboard-freeze-{os.getpid()}"
    run_s = (args.freezes * 2 * args.freeze_s + 60) * MAX_X_REALTIME
    cmd = [sys.executable, "-m", "hub.cli", "run", "configs/closed_loop.toml", "--quiet"]
    cmd += ["--mode", "lockstep", "--duration-s", f"{run_s:.0f}", "--runs-dir", str(tmp / "runs")]
    cmd += ["--session", session, *(a for item in args.run_set for a in ("--set", item))]
    with open(tmp / "run.err", "w") as err:
        run = child_popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=err)
    procs, frozen, cycles = [], [], []
    try:
        wait_for_steps(session, run)
        if args.watcher == "observer":  # the run's own: frozen, never ended here
            frozen.append(burst_observer_of(session))
        else:
            watcher, port = start_watcher(args.watcher, session, tmp / "watcher.log", [])
            procs.append(watcher)
        if args.watcher == "dashboard":  # a page that takes its frames, as a browser
            page = [sys.executable, "bench/dashboard_toggle.py", "--page-port", str(port)]
            procs.append(child_popen(page, cwd=ROOT, stdout=subprocess.DEVNULL))
        frozen += [proc.pid for proc in procs]
        time.sleep(args.settle_s)
        for i in range(args.freezes):
            t0 = time.time_ns()
            for pid in frozen:
                try:
                    os.kill(pid, signal.SIGSTOP)
                except ProcessLookupError:
                    raise SystemExit(f"process {pid} ended before freeze {i + 1}") from None
            time.sleep(args.freeze_s)
            t1 = time.time_ns()
            for pid in frozen:
                _continue(pid)
            time.sleep(args.freeze_s)
            cycles.append((t0, t1, time.time_ns()))
            print(f"  {i + 1}/{args.freezes} freezes", flush=True)
            if run.poll() is not None:
                raise SystemExit(f"the run ended early:\n{(tmp / 'run.err').read_text()[-2000:]}")
    finally:
        for pid in frozen:
            _continue(pid)
        end_watched_run(session, run, procs)
    (run_dir,) = (tmp / "runs").iterdir()
    return cycles, run_dir


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--watcher", choices=("bare", "dashboard", "observer"), default="bare")
    ap.add_argument("--freezes", type=int, default=8)
    ap.add_argument("--freeze-s", type=float, default=1.5, help="each freeze, and each run after")
    ap.add_argument("--settle-s", type=float, default=8.0, help="after the watcher starts")
    ap.add_argument("--run-set", action="append", default=[], metavar="KEY=VALUE",
                    help="config for the run (e.g. bus.low_latency=false)")  # fmt: skip
    args = ap.parse_args()
    end_children_on_signal()
    import numpy as np

    with tempfile.TemporaryDirectory() as tmp, StealMeter() as steal:
        cycles, run_dir = measure(args, Path(tmp))
        print("  reading the record", flush=True)
        rows = longest_gaps(np.sort(np.asarray(step_times_ns(run_dir), np.int64)), cycles)
    print(
        f"{'freeze':>6} {'steps frozen':>13} {'steps after':>12} {'longest gap':>12}  (from-to, ms)"
    )
    for i, row in enumerate(rows, 1):
        where = f"  ({row['gap_from_ms']}-{row['gap_to_ms']})" if "gap_ms" in row else ""
        print(f"{i:>6} {row['steps_frozen']:>13} {row['steps_running']:>12} "
              f"{row.get('gap_ms', float('nan')):>10.1f} ms{where}")  # fmt: skip
    gaps = [row.get("gap_ms", float("inf")) for row in rows]
    stalls = sum(g > 100 for g in gaps)
    print(
        f"{args.watcher} watcher frozen {args.freezes} times for {args.freeze_s:g} s: longest "
        f"gap between steps {max(gaps):.1f} ms; {stalls} freeze(s) with a gap over 100 ms; "
        f"CPU steal {steal.share:.1%}"
    )
    print(
        json.dumps(
            {
                "longest_gap_ms": max(gaps),
                "freezes_with_gap_over_100_ms": stalls,
                "gaps_ms": gaps,
                "steps_frozen": [row["steps_frozen"] for row in rows],
                "steps_running": [row["steps_running"] for row in rows],
                "watcher": args.watcher,
                "freezes": args.freezes,
                "freeze_s": args.freeze_s,
                "run_set": args.run_set,
                "steal_share": round(steal.share, 4),
            }
        )
    )


if __name__ == "__main__":
    main()
