"""The figures a benchmark derives from its runs (no run here: hand-built inputs)."""

import pytest

from bench.closed_loop import paired_cost


def test_equal_pairs_give_their_cost_with_no_spread():
    cost, lo, hi = paired_cost([0.9] * 8)
    assert cost == pytest.approx(0.1)
    assert lo == pytest.approx(0.1) and hi == pytest.approx(0.1)


def test_the_interval_holds_the_median_cost_and_widens_with_the_spread():
    narrow = paired_cost([0.92, 0.93, 0.94, 0.93, 0.92, 0.94])
    wide = paired_cost([0.80, 0.99, 0.85, 1.02, 0.88, 0.97])
    for cost, lo, hi in (narrow, wide):
        assert lo <= cost <= hi
    assert wide[2] - wide[1] > narrow[2] - narrow[1]
    assert narrow[0] == pytest.approx(1 - 0.93)


def test_a_faster_run_with_the_dashboard_is_a_negative_cost():
    cost, _, hi = paired_cost([1.05, 1.04, 1.06])
    assert cost < 0 and hi < 0
