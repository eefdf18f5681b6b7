"""The permutation test gives the p-values one can count by hand."""

import math

import pytest

from lab.stats import permutation_test


def test_fully_separated_samples_of_three_give_two_in_twenty():
    # 20 splits of 6 values into 3 + 3; only the observed one and its mirror are as extreme
    p, method = permutation_test([1, 2, 3], [4, 5, 6])
    assert p == pytest.approx(0.1) and method == "exact (20 relabellings)"


def test_identical_samples_give_one():
    assert permutation_test([2.0, 2.0, 2.0], [2.0, 2.0])[0] == 1.0


def test_overlapping_samples():
    # pooled 1, 2, 3, 4 split 2 + 2: means differ by |obs| = 2 for {1,2}|{3,4} and its mirror
    assert permutation_test([1, 2], [3, 4])[0] == pytest.approx(2 / 6)
    assert permutation_test([1, 4], [2, 3])[0] == pytest.approx(1.0)


def test_an_empty_side_has_no_p_value():
    p, method = permutation_test([], [1, 2])
    assert math.isnan(p) and "empty" in method


def test_large_samples_are_drawn_at_random_and_find_a_clear_difference():
    p, method = permutation_test(list(range(30)), [x + 100 for x in range(30)])
    assert method.startswith("random") and p < 0.001
