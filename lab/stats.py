"""Small statistics for comparing conditions: a two-sided permutation test of means.

Written out rather than imported: it is a few lines, exact for the sample sizes a
``compare`` gives (8 seeds a side: 12,870 relabellings), and needs no new dependency.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

#: relabellings enumerated exactly up to this many; beyond, drawn at random (seeded)
MAX_EXACT = 200_000
N_RANDOM = 20_000


def permutation_test(a, b, *, seed: int = 0) -> tuple[float, str]:
    """Two-sided p-value that the means of ``a`` and ``b`` differ only by chance.

    Every split of the pooled values into groups of ``len(a)`` and ``len(b)`` is equally
    likely under the null hypothesis; the p-value is the share of splits whose difference of
    means is at least as large (in absolute value) as the observed one.

    Parameters
    ----------
    a, b : array_like of float
        The two samples.
    seed : int
        For the random relabellings, drawn when there are more than :data:`MAX_EXACT`.

    Returns
    -------
    p_value : float
        nan when a side has no value.
    method : str
        ``exact (N relabellings)`` or ``random (N relabellings, seed S)``.
    """
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.size == 0 or b.size == 0:
        return math.nan, "none (an empty side)"
    pooled = np.concatenate([a, b])
    n, k = pooled.size, a.size
    total = pooled.sum()
    observed = abs(a.mean() - b.mean())
    tolerance = 1e-12 * max(1.0, float(np.abs(pooled).max()))

    def extreme(sums_a: np.ndarray) -> np.ndarray:
        diff = np.abs(sums_a / k - (total - sums_a) / (n - k))
        return diff >= observed - tolerance

    count = math.comb(n, k)
    if count <= MAX_EXACT:
        sums = np.fromiter(
            (pooled[list(idx)].sum() for idx in itertools.combinations(range(n), k)),
            dtype=np.float64,
            count=count,
        )
        return float(extreme(sums).mean()), f"exact ({count} relabellings)"
    rng = np.random.default_rng(seed)
    sums = np.array([rng.permutation(pooled)[:k].sum() for _ in range(N_RANDOM)])
    # the observed labelling counts as one of them: p is never 0
    p = (extreme(sums).sum() + 1) / (N_RANDOM + 1)
    return float(p), f"random ({N_RANDOM} relabellings, seed {seed})"
