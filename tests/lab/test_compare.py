"""A comparison tabulates each behaviour metric over the runs that have it."""

import json

import pytest

from hub.config import ConfigError
from lab.compare import Job, _tabulate, compare, format_table
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


def test_a_failed_run_is_listed_with_its_reason_and_the_conditions_are_tested(tmp_path):
    queue = [_job(tmp_path, "a", s, {"distance_m": float(s)}) for s in (1, 2, 3)]
    queue += [_job(tmp_path, "b", s, {"distance_m": 10.0 + s}) for s in (1, 2, 3)]
    queue[4].reason = "exit status 2: neuvision: run failed: culture/0 died at step 7"
    result = _tabulate(queue, ["a", "b"])
    assert [r["seed"] for r in result["runs"] if not r["ok"]] == [2]
    table = format_table(result, ["a", "b"])
    assert "**Failed runs: 1**" in table
    assert "| b | 2 | exit status 2: neuvision: run failed: culture/0 died at step 7 |" in table
    assert "| b | 2 | — |" in table  # its row in the per-seed table
    (test,) = result["tests"]
    assert (test["metric"], test["n_a"], test["n_b"]) == ("distance_m", 3, 2)
    assert test["p_value"] == pytest.approx(0.1)  # only the observed one of C(5, 3) = 10 splits
    assert "| distance (m) | a vs b | 3 vs 2 | 0.1000 | exact (10 relabellings) |" in table


@pytest.mark.parametrize(
    "bad, message",
    [
        ("culture.params.noise.sd=-1", "culture.params.noise.sd must be >= 0"),
        ("coding.params.bogus=1", "coding.params.bogus is not a parameter"),
        ('culture.params.config="nowhere.toml"', "nowhere.toml not found"),
    ],
)
def test_a_bad_parameter_of_any_condition_stops_the_comparison_before_its_first_run(
    tmp_path, bad, message
):
    out = tmp_path / "compare"
    with pytest.raises(ConfigError, match=message):
        compare(
            ["configs/closed_loop.toml", "configs/closed_loop_blind.toml"],
            seeds=1,
            overrides=[bad],
            out_dir=out,
        )
    assert not out.exists()
