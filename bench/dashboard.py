"""Benchmark of the live dashboard's data path, without a bus: CPU per view of each part.

A recorded closed-loop run is fed, step by step, through what the live path does with it:

1. the hub: each step's two replies taken and two inputs sent (:class:`hub.view.ObserverView`
   ``took``/``sent``), and every ``steps_per_view`` steps a view built, encoded and framed
   (:mod:`hub.wire`) — the part on the loop's own thread;
2. the dashboard: the frames reassembled (as :class:`hub.shelf.Asker` does), the view
   decoded and added to the page's state (:meth:`dashboard.observer.BusObserver._take`);
3. the frame for one page: :meth:`dashboard.state.FrameState.frame` and its JSON
   (:func:`dashboard.server.page_json`).

``steps_per_view`` is what a lockstep run at ``--x-realtime`` with ``loop.view_hz`` views
a second gives (a 10 ms period at 15x real time and 30 views/s: 50 steps). CPU time of this
process (``time.process_time``), so the figures do not depend on what else the host runs;
the share of a core is that CPU at the run's speed. The dashboard's cost to a lockstep loop
on two cores is measured end to end by ``bench/closed_loop.py --only-dashboard``; this
script says which part of the path the CPU goes to.

    python bench/dashboard.py                      # records a 20 s lockstep run first
    python bench/dashboard.py RUN_DIR --x-realtime 15 --view-hz 30

The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench import closed_loop  # noqa: E402
from bench.host import end_children_on_signal  # noqa: E402
from dashboard.observer import BusObserver  # noqa: E402
from dashboard.scene import build_scene, world_for  # noqa: E402
from dashboard.server import page_json  # noqa: E402
from dashboard.state import FrameState, Reader  # noqa: E402
from hub import wire  # noqa: E402
from hub.config import BusSection  # noqa: E402
from hub.protocol import MotorCommand, SensorReading, SpikeBatch, Stimulation  # noqa: E402
from hub.record import read_run  # noqa: E402
from hub.view import ObserverView  # noqa: E402


def record_run(seconds: float, runs_dir: Path) -> Path:
    """A lockstep closed-loop run of ``seconds`` (``bench/closed_loop.py``'s, whose child
    processes end with this script); its folder."""
    closed_loop.run("lockstep", seconds, runs_dir)
    (run_dir,) = [p for p in runs_dir.iterdir() if p.is_dir()]
    return run_dir


def steps_of(run_dir: Path) -> tuple[list[tuple], dict]:
    """Each step's (spikes, reading, stimulation, motor command), and the page's scene."""
    rec = read_run(run_dir)
    by_step: dict[int, list] = {}
    for slot, (kind, directions) in enumerate(
        [
            (SpikeBatch, ("rx",)),
            (SensorReading, ("rx",)),
            (Stimulation, ("tx",)),
            (MotorCommand, ("tx",)),
        ]  # fmt: skip
    ):
        for m in rec.decoded(kind, *directions):
            by_step.setdefault(m.step, [None] * 4)[slot] = m
    steps = [tuple(v) for _, v in sorted(by_step.items()) if None not in v]
    config = rec.manifest.get("config") or {}
    return steps, build_scene(rec.descriptions(), config, world_for(config))


def measure(steps: list[tuple], scene: dict, steps_per_view: int) -> dict:
    """CPU seconds of each part over all the steps, and the views' sizes."""
    run = steps[0][0].run
    view = ObserverView(run)
    view.watch(True)
    outbox_id = 0
    state = FrameState()
    state.set_scene(scene)
    observer = BusObserver(BusSection(), state)
    reader = Reader()
    cpu = {"hub_took_sent": 0.0, "hub_view": 0.0, "dashboard_take": 0.0, "page_frame": 0.0}
    views, view_bytes, frame_bytes = 0, 0, 0
    clock = time.process_time
    for i, (spikes, reading, stim, motor) in enumerate(steps, start=1):
        t0 = clock()
        view.sent(motor)
        view.sent(stim)
        view.took(reading)
        view.took(spikes)
        t1 = clock()
        cpu["hub_took_sent"] += t1 - t0
        if i % steps_per_view:
            continue
        t0 = clock()
        raw = view.build(i).encode()
        outbox_id += 1
        framed = wire.frames(raw, None, outbox_id)
        t1 = clock()
        inbox = wire.Inbox()  # as the dashboard's asker reassembles an answer's replies
        for payload, attachment in framed:
            whole = inbox.feed(bytes(payload), attachment)
            if whole is not None:
                observer._take("view", whole)
        t2 = clock()
        text = page_json(state.frame(reader))
        t3 = clock()
        cpu["hub_view"] += t1 - t0
        cpu["dashboard_take"] += t2 - t1
        cpu["page_frame"] += t3 - t2
        views += 1
        view_bytes += len(raw)
        frame_bytes += len(text)
    if observer.dropped:
        raise SystemExit(f"the dashboard dropped views: {dict(observer.dropped)}")
    return {"cpu_s": cpu, "views": views, "view_bytes": view_bytes, "frame_bytes": frame_bytes}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run_dir", nargs="?", help="a recorded closed-loop run (default: record one)")
    p.add_argument("--seconds", type=float, default=20.0, help="run time recorded if no RUN_DIR")
    p.add_argument("--x-realtime", type=float, default=15.0, help="the lockstep run's speed")
    p.add_argument("--view-hz", type=float, default=30.0, help="loop.view_hz")
    p.add_argument("--repeat", type=int, default=3, help="passes over the run (best kept)")
    args = p.parse_args()
    end_children_on_signal()  # a run recorded here ends with this script
    with tempfile.TemporaryDirectory() as tmp:
        if args.run_dir:
            run_dir = Path(args.run_dir)
        else:
            print(f"recording a {args.seconds:g} s lockstep closed-loop run ...", flush=True)
            run_dir = record_run(args.seconds, Path(tmp))
        steps, scene = steps_of(run_dir)
    period_s = steps[1][1].t_s - steps[0][1].t_s
    steps_per_s = args.x_realtime / period_s
    steps_per_view = max(1, round(steps_per_s / args.view_hz))
    spikes_per_step = sum(s[0].channel.size for s in steps) / len(steps)
    best = None
    for k in range(args.repeat):
        m = measure(steps, scene, steps_per_view)
        total = sum(m["cpu_s"].values())
        print(f"  pass {k + 1}: {total / m['views'] * 1e6:.0f} us of CPU per view", flush=True)
        if best is None or total < sum(best["cpu_s"].values()):
            best = m
    views = best["views"]
    per_view_us = {k: v / views * 1e6 for k, v in best["cpu_s"].items()}
    share = {k: v * 1e-6 * steps_per_s / steps_per_view for k, v in per_view_us.items()}
    print(
        f"{len(steps)} steps, {spikes_per_step:.0f} spikes a step, a view every "
        f"{steps_per_view} steps ({args.x_realtime:g}x real time, {args.view_hz:g} views/s): "
        f"{views} views of {best['view_bytes'] / views / 1e3:.1f} kB, frames of "
        f"{best['frame_bytes'] / views / 1e3:.1f} kB"
    )
    for k, us in per_view_us.items():
        print(f"  {k:16s} {us:8.0f} us a view   {share[k]:6.2%} of a core")
    print(f"  {'all':16s} {sum(per_view_us.values()):8.0f} us a view   {sum(share.values()):6.2%}")
    out = {f"{k}_us_per_view": round(v, 1) for k, v in per_view_us.items()}
    out.update({f"{k}_core_share": round(v, 4) for k, v in share.items()})
    out.update(
        steps_per_view=steps_per_view,
        spikes_per_step=round(spikes_per_step, 1),
        view_kb=round(best["view_bytes"] / views / 1e3, 1),
        frame_kb=round(best["frame_bytes"] / views / 1e3, 1),
    )
    print(json.dumps(out))


if __name__ == "__main__":
    main()
