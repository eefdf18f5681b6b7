"""What the dashboard's page costs the machine it runs on: a headless Chromium on a live run.

A closed-loop run with ``--dashboard`` (``configs/closed_loop.toml``; lockstep by default,
so each frame carries many steps' spikes) and the page open in Chromium (Debian's
``chromium``, as the browser tests use). Over ``--measure-s`` seconds, once the page shows
the run: the page's own time a frame taking the server's message (``JSON.parse`` and
storing it: ``nv.stats.takeMs``) and drawing (``nv.stats.drawMs``), the frames it received
and drew a second, and the CPU share of a core of the browser's processes (``/proc``) and
of the dashboard's (what its frames report). ``bench/closed_loop.py --only-dashboard``
measures what the dashboard costs the loop with a page that takes frames without
drawing them (a browser may run on another machine); this script measures the browser.

    python bench/page.py
    python bench/page.py --mode realtime --measure-s 20
    python bench/page.py --mode realtime --set dashboard.fps=10

The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.host import StealMeter, child_popen, end_children_on_signal  # noqa: E402
from hub.bus import free_tcp_port  # noqa: E402

TICKS_S = os.sysconf("SC_CLK_TCK")
PAGE_STATS = (
    "[nv.stats.received, nv.stats.drawn, nv.stats.takeMs, nv.stats.drawMs, nv.stats.serverCpu]"
)


def browser_cpu_s(root_pid: int, name_part: str = "chrom") -> float:
    """CPU seconds (user + system) of the processes under ``root_pid`` whose name holds
    ``name_part``."""
    parent, stat = {}, {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                text = f.read()
        except OSError:
            continue
        name = text[text.index("(") + 1 : text.rindex(")")]
        fields = text[text.rindex(")") + 2 :].split()
        pid = int(entry)
        parent[pid] = int(fields[1])
        stat[pid] = (name, (int(fields[11]) + int(fields[12])) / TICKS_S)
    total = 0.0
    for pid, (name, cpu_s) in stat.items():
        ancestor = pid
        while ancestor > 1 and ancestor != root_pid:
            ancestor = parent.get(ancestor, 1)
        if ancestor == root_pid and name_part in name:
            total += cpu_s
    return total


def wait_serving(url: str, proc, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        if proc.poll() is not None:
            raise SystemExit(f"page: the run ended (status {proc.returncode}) before serving")
        try:
            urllib.request.urlopen(url, timeout=1.0).close()
            return
        except OSError:
            if time.monotonic() > deadline:
                raise SystemExit(f"page: {url} did not answer in {timeout_s:g} s") from None
            time.sleep(0.3)


def main() -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    ap.add_argument("--measure-s", type=float, default=10.0, help="wall seconds measured")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a setting of the run (e.g. dashboard.fps=10); may be given again",
    )
    ap.add_argument(
        "--chromium", default=shutil.which("chromium") or shutil.which("chromium-browser")
    )
    args = ap.parse_args()
    if not args.chromium:
        raise SystemExit("page: no chromium on PATH (apt-get install chromium), or give --chromium")
    from playwright.sync_api import sync_playwright

    end_children_on_signal()
    port = free_tcp_port()
    with tempfile.TemporaryDirectory() as runs:
        cmd = [sys.executable, "-m", "hub.cli", "run", "configs/closed_loop.toml", "--quiet"]
        cmd += ["--mode", args.mode, "--duration-s", "3600", "--runs-dir", runs, "--dashboard"]
        cmd += ["--set", f"dashboard.port={port}"]
        cmd += [a for item in args.set for a in ("--set", item)]
        run = child_popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            wait_serving(f"http://127.0.0.1:{port}/", run)
            with sync_playwright() as pw:
                browser = pw.chromium.launch(executable_path=args.chromium, headless=True)
                page = browser.new_page(viewport={"width": 1400, "height": 1150})
                page.goto(f"http://127.0.0.1:{port}/")
                page.wait_for_function("nv.stats.connected && nv.step > 100", timeout=120_000)
                time.sleep(1.0)  # past the first frames, which carry everything kept
                print(f"measuring the page for {args.measure_s:g} s ...", flush=True)
                with StealMeter() as steal:
                    cpu0, wall0 = browser_cpu_s(os.getpid()), time.monotonic()
                    r0, d0, take0, draw0, _ = page.evaluate(PAGE_STATS)
                    time.sleep(args.measure_s)
                    r1, d1, take1, draw1, server_cpu = page.evaluate(PAGE_STATS)
                    cpu1, wall1 = browser_cpu_s(os.getpid()), time.monotonic()
                step = page.evaluate("nv.step")
                browser.close()
        finally:
            run.send_signal(signal.SIGINT)
            run.wait(timeout=60)
    wall_s = wall1 - wall0
    received, drawn = max(r1 - r0, 1), max(d1 - d0, 1)
    out = {
        "mode": args.mode,
        "sets": args.set,
        "page_take_ms_per_frame": round((take1 - take0) / received, 3),
        "page_draw_ms_per_frame": round((draw1 - draw0) / drawn, 3),
        "page_fps_received": round((r1 - r0) / wall_s, 1),
        "page_fps_drawn": round((d1 - d0) / wall_s, 1),
        "browser_cpu_core_share": round((cpu1 - cpu0) / wall_s, 4),
        "dashboard_cpu_core_share": round(server_cpu, 4),
        "steal_share": round(steal.share, 4),
    }
    print(
        f"{args.mode} closed loop, the page in headless Chromium over {wall_s:.1f} s (to step "
        f"{step:,}): {out['page_fps_received']} frames/s received, {out['page_fps_drawn']} "
        f"drawn; the page's time a frame {out['page_take_ms_per_frame']:.2f} ms taking it, "
        f"{out['page_draw_ms_per_frame']:.2f} ms drawing it; the browser's processes "
        f"{out['browser_cpu_core_share']:.1%} of a core, the dashboard's "
        f"{out['dashboard_cpu_core_share']:.1%}; CPU steal {out['steal_share']:.2%}"
    )
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
