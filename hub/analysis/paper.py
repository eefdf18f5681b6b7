"""The paper's reported figures (``../shared/reference/paper-targets.md``) and the ±30 % check.

One place for these numbers: the calibration script (``lab.calibrate``) and the
reproduction (``lab.reproduce``) both read them from here. Keys match the metrics dict
of ``hub.analysis.metrics``.
"""

from __future__ import annotations

import math

#: 15 min of spontaneous activity, 1024 neurons (paper 3.1, 3.2).
PAPER_TARGETS = {
    "mfr_hz": 3.41,
    "mfr_sd_hz": 6.32,
    "mbr_per_min": 3.12,
    "mnbr_per_min": 7.07,
    "nb_duration_ms": 71.29,
    "nb_duration_sd_ms": 6.36,
}

#: The figures judged against the paper: within ``TOLERANCE`` for one seed's reproduction.
CHECKED_KEYS = ("mfr_hz", "mbr_per_min", "mnbr_per_min", "nb_duration_ms")
TOLERANCE = 0.30
#: Over several seeds, each seed's figures within this band of the paper.
SEED_TOLERANCE = 0.20

#: PSTH after one stimulated excitatory neuron: the paper's peak (~60 ms) and the accepted range.
PAPER_PSTH_PEAK_MS = 60.0
PSTH_PEAK_RANGE_MS = (30.0, 100.0)

#: The paper's evoked protocol: monophasic pulses of 10 ms and 100 µA at 0.2 Hz, the first
#: one 1 s into the protocol.
PULSE_AMPLITUDE_UA = 100.0
PULSE_WIDTH_MS = 10.0
PULSE_PERIOD_MS = 5000.0
FIRST_PULSE_AFTER_MS = 1000.0


def relative_error(value, target: float) -> float:
    """The relative error of a figure against the paper's.

    Parameters
    ----------
    value : float or None
        Our figure (None or NaN: missing).
    target : float
        The paper's.

    Returns
    -------
    float
        ``value / target - 1``; NaN when the value is missing.
    """
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return math.nan
    return float(value) / target - 1.0


def within(value, target: float, tolerance: float = TOLERANCE) -> bool:
    """Whether a figure matches the paper's.

    Parameters
    ----------
    value : float or None
    target : float
    tolerance : float
        Relative (default ``TOLERANCE``).

    Returns
    -------
    bool
        ``value`` lies within ``±tolerance`` of ``target`` (False when missing).
    """
    err = relative_error(value, target)
    return not math.isnan(err) and abs(err) <= tolerance
