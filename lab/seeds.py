"""Seed lists and per-seed summaries for the multi-seed checks of the simulated culture.

``parse_seeds("1-6")`` is how ``neuvision reproduce --seeds`` and ``python -m lab.calibrate
--seeds`` read their seed lists; ``mean_sd`` is how they summarise a figure over seeds.
"""

from __future__ import annotations

import math


def parse_seeds(text: str) -> list[int]:
    """Seeds from a list such as ``"1-6"``, ``"1,3,5"`` or ``"1-3,8"``.

    Parameters
    ----------
    text : str
        Comma-separated seeds or inclusive ranges ``a-b`` of non-negative integers.

    Returns
    -------
    list of int
        In the order given, without repeats.

    Raises
    ------
    ValueError
        For an empty list, a malformed item or a range whose end precedes its start.
    """
    seeds: list[int] = []
    for item in str(text).split(","):
        item = item.strip()
        lo, sep, hi = item.partition("-")
        if not lo.isdigit() or (sep and not hi.isdigit()):
            raise ValueError(f"seeds: {item!r} is not a seed or a range a-b (e.g. 1-6 or 1,3,5)")
        a, b = int(lo), int(hi) if sep else int(lo)
        if b < a:
            raise ValueError(f"seeds: the range {item!r} ends before it starts")
        seeds += [s for s in range(a, b + 1) if s not in seeds]
    return seeds


def mean_sd(values) -> dict:
    """Mean and s.d. (ddof 1) of a figure over seeds, ignoring missing values.

    Parameters
    ----------
    values : iterable of float or None

    Returns
    -------
    dict
        ``mean``, ``sd`` (None when fewer than two values) and ``n``.
    """
    xs = [float(v) for v in values if v is not None and not math.isnan(float(v))]
    n = len(xs)
    if n == 0:
        return {"mean": None, "sd": None, "n": 0}
    mean = sum(xs) / n
    sd = math.sqrt(sum((x - mean) ** 2 for x in xs) / (n - 1)) if n > 1 else None
    return {"mean": mean, "sd": sd, "n": n}
