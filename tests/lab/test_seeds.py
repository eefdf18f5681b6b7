"""Seed lists and per-seed summaries (lab.seeds), and the per-seed table of lab.calibrate."""

import math

import pytest

from lab.calibrate import seed_table
from lab.seeds import mean_sd, parse_seeds


@pytest.mark.parametrize(
    ("text", "seeds"),
    [("1-6", [1, 2, 3, 4, 5, 6]), ("3", [3]), ("1,3,5", [1, 3, 5]), ("1-3,2,8", [1, 2, 3, 8])],
)
def test_seed_lists(text, seeds):
    assert parse_seeds(text) == seeds


@pytest.mark.parametrize(("text", "message"), [("", "not a seed"), ("a-b", "not a seed"),
                                               ("6-1", "ends before it starts"),
                                               ("1,-2", "not a seed")])  # fmt: skip
def test_bad_seed_lists_are_rejected_by_name(text, message):
    with pytest.raises(ValueError, match=message):
        parse_seeds(text)


def test_mean_and_sd_over_seeds_skip_missing_values():
    s = mean_sd([1.0, 2.0, None, 3.0, math.nan])
    assert s == {"mean": 2.0, "sd": 1.0, "n": 3}
    assert mean_sd([4.0]) == {"mean": 4.0, "sd": None, "n": 1}
    assert mean_sd([None]) == {"mean": None, "sd": None, "n": 0}


def test_seed_table_marks_figures_outside_the_band_and_summarises():
    rows = [
        {"seed": 1, "mbr_per_min": 3.12, "nb_participation": 0.4},
        {"seed": 2, "mbr_per_min": 4.0, "nb_participation": 0.5},
    ]
    table = seed_table(rows, ("mbr_per_min", "nb_participation"), tolerance=0.2)
    lines = table.splitlines()
    assert lines[2] == "| paper | 3.12 | — |"
    assert lines[3] == "| 1 | 3.12 (+0 %) | 0.40 |"
    assert lines[4] == "| 2 | **4.00 (+28 %)** | 0.50 |"
    assert lines[5] == "| mean ± s.d. | 3.56 ± 0.62 | 0.45 ± 0.07 |"
