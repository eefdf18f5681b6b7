"""The trivial lockstep loop of two versions, interleaved: what a change costs the loop.

Each side is a tree of this project (a ``git worktree`` of another commit, or this one)
and runs its *own* ``bench/loop.py``: ``run_once("lockstep", 10.0, STEPS)``, the hub and
two trivial endpoints placed by the OS, in a fresh process per run. The runs alternate
A B, B A, B A, A B, ... so that the host's drift over the session falls on both sides alike; each
pair's ratio B/A gives the cost with a 90 % interval (``bench/closed_loop.py``'s
:func:`paired_cost`). A side may add ``--set`` items to its runs (``TREE|KEY=VALUE;...``).
More sides (``A B C ...``) run in rounds, one run of each side a round, the order rotated
and reversed from round to round; each side's cost is against A, from the rounds' ratios.

With ``--closed-loop SECONDS`` each run is instead the tree's own ``neuvision run
configs/closed_loop.toml --mode lockstep`` (the 1024-neuron culture and the arena: what
``bench/closed_loop.py`` times), and the figure its steps per second from the run's
manifest; each tree first runs it once unmeasured (its simulator's kernels compiled and
cached).

    git worktree add /tmp/before 5231a2d
    python bench/loop_ab.py /tmp/before . --pairs 6 --steps 10000
    python bench/loop_ab.py . ".|online.enabled=false" --pairs 4
    python bench/loop_ab.py /tmp/before . --pairs 6 --closed-loop 60
    python bench/loop_ab.py /tmp/before . --pairs 6 --placed
    python bench/loop_ab.py /tmp/before /tmp/previous . --pairs 8   # three sides

Placement matters: with ``--placed`` both sides run as ``bench/loop.py``'s first figure
does, the hub on a CPU of its own and the endpoints on the others (``loop.cpus``,
``body.cpus``, ``culture.cpus``); without it the OS places every thread. A change can win
one and lose the other (Zenoh's thread settings once did: 2.8 % faster placed by the OS,
23 % slower placed): measure both.

So does whether idle CPUs may sleep: a tree since ``loop.keep_cpus_awake`` (default on)
keeps them awake while it steps, and a tree before it does not. ``--cpus-awake`` keeps them
awake for the whole A/B, from this script (Linux PM QoS, :func:`hub.scheduling.hold_cpus_awake`),
so that every side runs so: like for like. Without it each side runs as it would for a user.

The last line printed is one JSON object (``steps_per_s_a``, ``steps_per_s_b``: medians;
``cost_share_paired`` and ``cost_share_interval_90``; ``steal_share``).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
# Each side's processes take Zenoh's thread settings from their own tree (hub/bus.py sets
# ZENOH_RUNTIME when imported, and keeps one already set): importing this tree's hub below
# sets it here, and the runs would inherit it. One the user set is given to both sides.
USER_ZENOH_RUNTIME = os.environ.get("ZENOH_RUNTIME")

from bench.closed_loop import paired_cost  # noqa: E402
from bench.host import StealMeter, child_run, end_children_on_signal  # noqa: E402
from bench.loop import placement  # noqa: E402
from hub.scheduling import hold_cpus_awake  # noqa: E402

# Run in the side's tree, with that tree first on the path (its hub, its endpoints).
PROGRAM = """
import json, os, sys
sys.path.insert(0, os.getcwd())
os.environ["PYTHONPATH"] = os.getcwd()
from bench.loop import run_once
timing = run_once("lockstep", 10.0, {steps}, *{sets!r})
print("RESULT", json.dumps({{"steps_per_s": timing["steps_per_s"]}}))
"""


def side(spec: str) -> tuple[Path, list[str]]:
    """``TREE`` or ``TREE|KEY=VALUE;KEY=VALUE``: the tree and its runs' ``--set`` items."""
    tree, _, sets = spec.partition("|")
    path = Path(tree).resolve()
    if not (path / "bench" / "loop.py").is_file():
        raise SystemExit(f"loop_ab: {tree} has no bench/loop.py")
    return path, [s for s in sets.split(";") if s]


def side_env(tree: Path) -> dict[str, str]:
    """The environment of a side's runs: its tree first on the path, and Zenoh's threads as
    its tree sets them (or as the user set them for both)."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    if USER_ZENOH_RUNTIME is None:
        env.pop("ZENOH_RUNTIME", None)
    return env


def run(tree: Path, sets: list[str], steps: int) -> float:
    """One run of the tree's trivial lockstep loop; its steps per second."""
    program = PROGRAM.format(steps=steps, sets=sets)
    done = child_run([sys.executable, "-c", program], cwd=tree, env=side_env(tree))
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    if done.returncode != 0 or not lines:
        raise SystemExit(f"loop_ab: a run in {tree} failed:\n{done.stderr[-2000:]}")
    return json.loads(lines[-1].removeprefix("RESULT "))["steps_per_s"]


def run_closed_loop(tree: Path, sets: list[str], seconds: float) -> float:
    """One lockstep run of the tree's configs/closed_loop.toml; its steps per second."""
    with tempfile.TemporaryDirectory() as runs:
        cmd = [sys.executable, "-m", "hub.cli", "run", "configs/closed_loop.toml", "--quiet"]
        cmd += ["--mode", "lockstep", "--duration-s", str(seconds), "--runs-dir", runs]
        for item in sets:
            cmd += ["--set", item]
        done = child_run(cmd, cwd=tree, env=side_env(tree))
        manifests = list(Path(runs).glob("*/manifest.json"))
        if done.returncode != 0 or len(manifests) != 1:
            raise SystemExit(f"loop_ab: a closed-loop run in {tree} failed:\n{done.stderr[-2000:]}")
        return json.loads(manifests[0].read_text())["timing"]["steps_per_s"]


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("a", help="the side measured against (TREE or TREE|KEY=VALUE;...)")
    ap.add_argument("b", help="the side whose cost is measured")
    ap.add_argument("more", nargs="*", help="more sides, each measured against A")
    ap.add_argument("--pairs", type=int, default=4)
    ap.add_argument("--steps", type=int, default=10_000)
    ap.add_argument(
        "--closed-loop",
        type=float,
        metavar="SECONDS",
        help="A/B the closed loop instead (lockstep runs of this many seconds of run time)",
    )
    ap.add_argument(
        "--placed",
        action="store_true",
        help="the hub on a CPU of its own, the endpoints on the others (both sides)",
    )
    ap.add_argument(
        "--cpus-awake",
        action="store_true",
        help="keep idle CPUs awake for every side's runs (PM QoS held by this script)",
    )
    args = ap.parse_args(argv)
    if args.pairs < 1 or args.steps < 100:
        ap.error("--pairs must be >= 1 and --steps >= 100")
    if args.closed_loop is not None and args.closed_loop <= 0:
        ap.error("--closed-loop must be > 0")
    end_children_on_signal()
    if len(args.more) > 24:
        ap.error("at most 26 sides")
    specs = {"a": args.a, "b": args.b, **{chr(ord("c") + k): m for k, m in enumerate(args.more)}}
    sides = {name: side(spec) for name, spec in specs.items()}
    if args.placed:
        overrides, where = placement()
        if not overrides:
            ap.error(f"--placed needs two CPUs or more: {where}")
        sides = {name: (tree, [*overrides, *sets]) for name, (tree, sets) in sides.items()}
    if args.closed_loop is None:
        what = f"{args.steps:,} lockstep steps"

        def measure(name):
            return run(*sides[name], args.steps)
    else:
        what = f"{args.closed_loop:g} s closed-loop lockstep runs"

        def measure(name):
            return run_closed_loop(*sides[name], args.closed_loop)

        for name in sides:  # kernels compiled and cached, unmeasured
            print(f"warming up {name}: a {min(args.closed_loop, 2.0):g} s run", flush=True)
            run_closed_loop(*sides[name], min(args.closed_loop, 2.0))
    figures: dict[str, list[float]] = {name: [] for name in sides}
    awake = hold_cpus_awake(args.cpus_awake)
    if args.cpus_awake and not awake.held:
        ap.error(f"--cpus-awake: {awake.reason}")
    try:
        with StealMeter() as steal:
            for i in range(args.pairs):
                for name in run_order(list(sides), i):
                    figures[name].append(measure(name))
                    print(f"pair {i + 1}, {name}: {figures[name][-1]:,.0f} steps/s", flush=True)
    finally:
        awake.release()
    median = {name: statistics.median(runs) for name, runs in figures.items()}
    costs = {
        name: paired_cost([x / a for a, x in zip(figures["a"], runs, strict=True)])
        for name, runs in figures.items()
        if name != "a"
    }
    placed = " (hub on a CPU of its own)" if args.placed else ""
    placed += " (idle CPUs kept awake for every side)" if args.cpus_awake else ""
    for name, (cost, lo, hi) in costs.items():
        print(
            f"{args.pairs} interleaved {'pairs' if len(sides) == 2 else 'rounds'} of {what}"
            f"{placed}: A {median['a']:,.0f}, {name.upper()} {median[name]:,.0f} steps/s "
            f"(medians); {name.upper()}'s cost {100 * cost:+.1f} % from the ratios (90 % "
            f"interval {100 * lo:+.1f} to {100 * hi:+.1f} %); CPU steal {100 * steal.share:.2f} %"
        )
    cost, lo, hi = costs["b"]
    out = {
        "a": args.a,
        "b": args.b,
        "bench": "closed_loop" if args.closed_loop else "loop",
        "placed": args.placed,
        "cpus_awake": args.cpus_awake,
        "steps_per_s_a": round(median["a"], 1),
        "steps_per_s_b": round(median["b"], 1),
        "runs_steps_per_s": {k: [round(v, 1) for v in vs] for k, vs in figures.items()},
        "cost_share_paired": round(cost, 4),
        "cost_share_interval_90": [round(lo, 4), round(hi, 4)],
        "steal_share": round(steal.share, 4),
    }
    if args.more:  # each further side, as B's figures above
        out["more"] = {
            name: {
                "side": specs[name],
                "steps_per_s": round(median[name], 1),
                "cost_share_paired": round(costs[name][0], 4),
                "cost_share_interval_90": [round(costs[name][1], 4), round(costs[name][2], 4)],
            }
            for name in costs
            if name != "b"
        }
    print(json.dumps(out))
    return out


def run_order(names: list[str], round_index: int) -> list[str]:
    """The sides' order in one round: A B, B A, B A, A B, ... for two sides (each side as
    often first as last over every two rounds); with more, rotated every two rounds and
    reversed every other one."""
    k = (round_index // 2) % len(names)
    order = names[k:] + names[:k]
    return order[::-1] if round_index % 2 else order


if __name__ == "__main__":
    main()
