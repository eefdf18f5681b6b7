"""The host's floor for a realtime loop: how late a thread that does nothing but wake on a
period wakes.

The hub's realtime scheduler waits for each step's start in ``queue.Queue.get`` with a
timeout, under ``SCHED_FIFO``, with idle CPUs kept awake (docs/architecture.md). Here a
lone thread does the same and no more — no bus, no endpoints — so the share of its wakes
later than a quarter period (what makes a realtime step *late*) is what the machine itself
allows: a loop cannot be late less often than this. Each round measures the hub's way of
waiting (a queue) and a plain ``time.sleep``, alternating, and says the CPU steal during it.

    python bench/wake_floor.py                    # 1 ms, 10,000 wakes a round, 3 rounds
    python bench/wake_floor.py --period-ms 10 --wakes 2000
    python bench/wake_floor.py --cpus-sleep       # idle CPUs left to sleep

The last line printed is one JSON object: ``wake_late_share_queue`` and
``wake_late_share_sleep`` (the medians of the rounds), ``wake_p99_ms_queue``,
``wake_max_ms_queue``, ``steal_share``, and each round's figures.
"""

from __future__ import annotations

import argparse
import json
import queue
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.host import StealMeter  # noqa: E402
from hub.realtime import LATE_START_SHARE  # noqa: E402
from hub.scheduling import hold_cpus_awake, raise_threads, restore_threads  # noqa: E402


def lateness_s(period_s: float, wakes: int, how: str) -> np.ndarray:
    """How late each of ``wakes`` wakes on a ``period_s`` schedule came (s); ``how`` is
    ``"queue"`` (a timed ``Queue.get``, as the hub waits) or ``"sleep"``."""
    inbox: queue.Queue = queue.Queue()
    late = np.empty(wakes)
    t0 = time.monotonic()
    for k in range(wakes):
        target = t0 + (k + 1) * period_s
        while (now := time.monotonic()) < target:
            if how == "sleep":
                time.sleep(target - now)
            else:
                try:
                    inbox.get(timeout=target - now)
                except queue.Empty:
                    pass
        late[k] = now - target
    return late


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--period-ms", type=float, default=1.0)
    ap.add_argument("--wakes", type=int, default=10_000, help="wakes a round, each way")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--priority", type=int, default=10, help="SCHED_FIFO priority (0: none)")
    ap.add_argument("--cpus-sleep", action="store_true", help="do not keep idle CPUs awake")
    args = ap.parse_args(argv)
    if args.period_ms <= 0 or args.wakes < 100 or args.rounds < 1:
        ap.error("--period-ms must be > 0, --wakes >= 100 and --rounds >= 1")
    period_s = args.period_ms / 1e3
    awake = hold_cpus_awake(not args.cpus_sleep)
    sched = raise_threads(args.priority, [0])  # this thread alone
    print(
        f"a thread waking every {args.period_ms:g} ms, {args.wakes:,} wakes a round; "
        f"scheduling {sched.policy}{' ' + str(sched.priority) if sched.priority else ''}"
        f"{'' if sched.policy == 'fifo' else ' (' + sched.reason + ')'}; idle CPUs "
        f"{'kept awake' if awake.held else 'may sleep: ' + awake.reason}",
        flush=True,
    )
    late_after_s = LATE_START_SHARE * period_s
    rounds = []
    try:
        with StealMeter() as steal:
            for i in range(args.rounds):
                order = ("queue", "sleep") if i % 2 == 0 else ("sleep", "queue")
                got = {}
                for how in order:
                    with StealMeter() as round_steal:
                        late_ms = lateness_s(period_s, args.wakes, how) * 1e3
                    got[how] = {
                        "late_share": float(np.mean(late_ms > late_after_s * 1e3)),
                        "p99_ms": float(np.percentile(late_ms, 99)),
                        "max_ms": float(late_ms.max()),
                        "steal_share": round_steal.share,
                    }
                    print(
                        f"round {i + 1}, {how:5}: {100 * got[how]['late_share']:.2f} % of "
                        f"wakes over {late_after_s * 1e3:.2f} ms late, p99 "
                        f"{got[how]['p99_ms']:.3f} ms, max {got[how]['max_ms']:.2f} ms "
                        f"(CPU steal {100 * round_steal.share:.2f} %)",
                        flush=True,
                    )
                rounds.append(got)
    finally:
        restore_threads(sched)
        awake.release()

    def median(how: str, key: str) -> float:
        return statistics.median(r[how][key] for r in rounds)

    out = {
        "period_ms": args.period_ms,
        "wakes_per_round": args.wakes,
        "scheduling": sched.policy,
        "cpus_awake": awake.held,
        "wake_late_share_queue": round(median("queue", "late_share"), 5),
        "wake_late_share_sleep": round(median("sleep", "late_share"), 5),
        "wake_p99_ms_queue": round(median("queue", "p99_ms"), 4),
        "wake_max_ms_queue": round(max(r["queue"]["max_ms"] for r in rounds), 3),
        "steal_share": round(steal.share, 5),
        "rounds": rounds,
    }
    print(
        f"medians of {args.rounds} rounds: {100 * out['wake_late_share_queue']:.2f} % of wakes "
        f"late waiting as the hub does, {100 * out['wake_late_share_sleep']:.2f} % sleeping; "
        f"CPU steal {100 * steal.share:.2f} %"
    )
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
