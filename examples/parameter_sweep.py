"""A parameter sweep: how the decoder's turn gain changes where the robot goes.

    python examples/parameter_sweep.py              # 4 gains x 30 s
    python examples/parameter_sweep.py 10           # 4 gains x 10 s

One run per value of ``decoding.params.turn_gain_rad_s_per_rad``; prints a small table.
"""

import sys
from pathlib import Path

from neuvision import Experiment

CONFIGS = Path(__file__).resolve().parent.parent / "configs"

GAINS = (1.0, 2.0, 4.0, 6.0)


def main(duration_s: float = 30.0, runs_dir: str = "runs") -> list[dict]:
    exp = Experiment(CONFIGS / "closed_loop.toml", {"experiment.duration_s": duration_s})
    rows = []
    for gain in GAINS:
        exp.set("decoding.params.turn_gain_rad_s_per_rad", gain)
        b = exp.run(runs_dir=runs_dir).summary["behaviour"]
        rows.append({"gain": gain, **b})
    print(f"{'turn gain':>10} {'distance m':>11} {'obstacle entries':>17} {'coverage':>9}")
    for r in rows:
        print(f"{r['gain']:10.1f} {r['distance_m']:11.2f} {r['obstacle_entries']:17d} "
              f"{r['coverage_fraction']:9.2f}")  # fmt: skip
    return rows


if __name__ == "__main__":
    main(*(float(a) for a in sys.argv[1:2]))
