"""The calibrated cultures against the paper on every seed (issue 21), through the library.

Seeds 1–6, 300 s of spontaneous activity each after a 5 s warm-up, the figures computed by
``hub.analysis`` as ``neuvision reproduce`` computes them (``lab.calibrate``), two seeds at a
time: about 25 s for both cultures on this 2-core machine. Then the default culture's headline
stimulation protocol per seed (one excitatory neuron, 60 pulses, as ``neuvision reproduce``
runs it: about 20 s more): its PSTH peak and the regularity of its evoked CATs.

The default culture meets all four spontaneous figures, the MFR spread, the PSTH peak and the
CAT regularity on every seed. What is missed is listed (``KNOWN_MISSES``, ``PSTH_MISSES``) and
expected to fail (strictly: a miss that starts passing fails the test, so
that the lists are kept true); the culture before issue 21 (``culture_1024_local.toml``, kept to
compare against) misses three of the four spontaneous figures.
"""

from concurrent.futures import ProcessPoolExecutor

import pytest

from hub.analysis.paper import (
    CHECKED_KEYS,
    PAPER_TARGETS,
    PSTH_PEAK_RANGE_MS,
    SEED_TOLERANCE,
    relative_error,
    within,
)
from lab.calibrate import statistics_over_seeds
from lab.reproduce import CAT_REGULARITY_RATIO, headline_evoked_statistics
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
#: seeds whose PSTH peak after one excitatory neuron misses the paper's 30-100 ms
PSTH_MISSES: dict[int, str] = {}
_cache: dict[str, list[dict]] = {}
_evoked: dict[int, dict] = {}


def per_seed(culture: str) -> list[dict]:
    """The figures of every seed of one culture (simulated once per test session)."""
    if culture not in _cache:
        _cache[culture] = statistics_over_seeds(load_config(culture), SEEDS, SECONDS, jobs=2)
    return _cache[culture]


def _cases():
    for culture in (DEFAULT, LOCAL):
        for key in CHECKED_KEYS:
            miss = KNOWN_MISSES.get((culture, key))
            why = f"the culture before issue 21, kept to compare: {miss}"
            marks = [pytest.mark.xfail(strict=True, reason=why)]
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


def evoked(seed: int) -> dict:
    """The headline protocol of the default culture, every seed simulated once per session."""
    if not _evoked:
        cfg = load_config(DEFAULT)
        with ProcessPoolExecutor(max_workers=2) as pool:
            rows = pool.map(headline_evoked_statistics, [cfg] * len(SEEDS), SEEDS)
            _evoked.update({r["seed"]: r for r in rows})
    return _evoked[seed]


def _seed_cases(misses: dict):
    for seed in SEEDS:
        miss = misses.get(seed)
        marks = [pytest.mark.xfail(strict=True, reason=f"issue 21, not met: {miss}")]
        yield pytest.param(seed, marks=marks if miss else [], id=f"seed{seed}")


@pytest.mark.slow
@pytest.mark.parametrize("seed", list(_seed_cases(PSTH_MISSES)))
def test_one_stimulated_excitatory_neuron_evokes_a_psth_peak_at_30_to_100_ms(seed):
    # the paper's 60 pulses of 10 ms, 100 µA, 0.2 Hz, as neuvision reproduce gives them
    r = evoked(seed)
    lo, hi = PSTH_PEAK_RANGE_MS
    assert r["n_evoked_nb"] >= 10, r  # a peak made by evoked network bursts
    assert lo <= r["psth_peak_ms"] <= hi, r


@pytest.mark.slow
@pytest.mark.parametrize("seed", list(_seed_cases({})))
def test_evoked_cats_are_more_regular_than_spontaneous_ones(seed):
    spont = next(r for r in per_seed(DEFAULT) if r["seed"] == seed)["cat_spread"]
    ev = evoked(seed)["cat_spread_evoked"]
    assert ev is not None and ev <= CAT_REGULARITY_RATIO * spont, (ev, spont)
