"""The calibrated cultures against the paper on every seed (issue 21), through the library.

Seeds 1–6, 300 s of spontaneous activity each after a 5 s warm-up, the figures computed by
``hub.analysis`` as ``neuvision reproduce`` computes them (``lab.calibrate``), two seeds at a
time: about 25 s for both cultures on this 2-core machine.

The default culture meets all four on every seed. The culture before issue 21
(``culture_1024_local.toml``, kept to compare against) does not: the figures it misses are
listed in ``KNOWN_MISSES`` and expected to fail (strictly: a miss that starts passing fails the
test, so that the list is kept true).
"""

import pytest

from hub.analysis.paper import CHECKED_KEYS, PAPER_TARGETS, SEED_TOLERANCE, relative_error, within
from lab.calibrate import statistics_over_seeds
from sim_network import load_config

SEEDS = range(1, 7)
SECONDS = 300.0
DEFAULT = "configs/culture_1024.toml"
LOCAL = "configs/culture_1024_local.toml"  # the culture before issue 21, for comparison
KNOWN_MISSES = {
    # MBR ≈ 0.8 × MNBR where the paper implies ≈ 0.45: both cannot sit in the band
    (LOCAL, "mbr_per_min"): "MBR +15 to +66 % over seeds 1-6",
    (LOCAL, "mnbr_per_min"): "MNBR -9 to -38 %",
    (LOCAL, "nb_duration_ms"): "network bursts of 57-59 ms: seed 4 at -21 %",
}
_cache: dict[str, list[dict]] = {}


def per_seed(culture: str) -> list[dict]:
    """The figures of every seed of one culture (simulated once per test session)."""
    if culture not in _cache:
        _cache[culture] = statistics_over_seeds(load_config(culture), SEEDS, SECONDS, jobs=2)
    return _cache[culture]


def _cases():
    for culture in (DEFAULT, LOCAL):
        for key in CHECKED_KEYS:
            miss = KNOWN_MISSES.get((culture, key))
            marks = [pytest.mark.xfail(strict=True, reason=f"issue 21, not met: {miss}")]
            yield pytest.param(culture, key, marks=marks if miss else [], id=f"{culture}-{key}")


@pytest.mark.slow
@pytest.mark.parametrize(("culture", "key"), list(_cases()))
def test_every_seed_is_within_20_percent_of_the_paper(culture, key):
    rows = per_seed(culture)
    assert [r["seed"] for r in rows] == list(SEEDS)
    ref = PAPER_TARGETS[key]
    outside = {
        r["seed"]: f"{r[key]:.2f} ({100 * relative_error(r[key], ref):+.0f} %)"
        for r in rows
        if not within(r[key], ref, SEED_TOLERANCE)
    }
    assert outside == {}


@pytest.mark.slow
@pytest.mark.parametrize("culture", [DEFAULT, LOCAL])
def test_firing_rates_spread_across_neurons_as_in_the_paper(culture):
    paper = PAPER_TARGETS["mfr_sd_hz"] / PAPER_TARGETS["mfr_hz"]  # s.d. ≈ 1.85 × mean
    for r in per_seed(culture):
        assert r["mfr_sd_hz"] / r["mfr_hz"] == pytest.approx(paper, rel=0.3), r["seed"]
