"""A comparison tabulates each behaviour metric over the runs that have it."""

import json

from lab.compare import Job, _tabulate, format_table
from lab.postrun import SUMMARY_FILE


def _job(tmp_path, name, seed, behaviour):
    run_dir = tmp_path / name / f"seed{seed}" / "run"
    run_dir.mkdir(parents=True)
    summary = {"behaviour": behaviour, "timing": {"x_realtime": 10.0}}
    (run_dir / SUMMARY_FILE).write_text(json.dumps(summary))
    return Job("x.toml", name, seed, run_dir.parent, status=0, run_dir=run_dir)


def test_metrics_are_averaged_over_the_runs_that_have_them(tmp_path):
    arena = {"distance_m": 1.0, "obstacle_entries": 2, "mean_speed_mps": 0.1}
    queue = [
        _job(tmp_path, "sim", 1, arena),
        _job(tmp_path, "sim", 2, {**arena, "distance_m": 3.0, "obstacle_entries": 4}),
        # a real body in an unknown arena: path metrics only
        _job(tmp_path, "real", 1, {"distance_m": 2.0, "mean_speed_mps": 0.2}),
    ]
    result = _tabulate(queue, ["sim", "real"])
    assert result["stats"]["sim"]["distance_m"] == {"mean": 2.0, "sd": 2**0.5, "n": 2}
    assert result["stats"]["real"]["distance_m"]["n"] == 1
    assert result["stats"]["real"]["obstacle_entries"] == {"mean": None, "sd": None, "n": 0}
    table = format_table(result, ["sim", "real"])
    assert "| obstacle entries | 3.00 ± 1.41 (n=2) | — |" in table
