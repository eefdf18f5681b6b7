"""The paper's closed loop against its blind control, over a few seeds, from Python.

    python examples/paper_closed_loop.py            # 3 seeds x 60 s per condition
    python examples/paper_closed_loop.py 2 10       # 2 seeds x 10 s

Prints each run's distance travelled and obstacle entries, then the means.
"""

import sys
from pathlib import Path

from neuvision import Experiment

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def main(seeds: int = 3, duration_s: float = 60.0, runs_dir: str = "runs") -> dict:
    results = {}
    for name in ("closed_loop", "closed_loop_blind"):
        exp = Experiment(CONFIGS / f"{name}.toml", {"experiment.duration_s": duration_s})
        results[name] = []
        for seed in range(1, seeds + 1):
            run = exp.set("experiment.seed", seed).run(runs_dir=runs_dir)
            b = run.summary["behaviour"]
            results[name].append(b)
            print(
                f"{name:18s} seed {seed}: {b['distance_m']:.2f} m travelled, "
                f"{b['obstacle_entries']} obstacle entries"
            )
    for name, runs in results.items():
        entries = sum(b["obstacle_entries"] for b in runs) / len(runs)
        print(f"{name:18s} mean obstacle entries per run: {entries:.2f}")
    return results


if __name__ == "__main__":
    main(*(int(sys.argv[1]),) if len(sys.argv) > 1 else (),
         **({"duration_s": float(sys.argv[2])} if len(sys.argv) > 2 else {}))  # fmt: skip
