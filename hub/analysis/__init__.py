"""Spike-train analysis of any culture (simulated neurons or electrodes), as plain numpy.

Modules: ``spikes`` (rates, ISI, PSTH, instantaneous rate), ``bursts``, ``network_bursts``,
``center_of_activity`` (CA, CAT, CAT spread), ``metrics`` (the whole analysis and its metrics
dict), ``online`` (incremental burst / network-burst detector), ``figures`` (matplotlib) and
``report`` (self-contained HTML). ``figures`` is not imported here so that the hub's online
path never loads matplotlib.
"""

from hub.analysis.bursts import BURST_DTYPE, BurstParams, detect_bursts
from hub.analysis.center_of_activity import (
    Cat,
    cat_spread,
    center_of_activity,
    center_of_activity_trajectories,
)
from hub.analysis.metrics import AnalysisParams, AnalysisResult, analyze, compute_metrics
from hub.analysis.network_bursts import NetworkBurstParams, NetworkBursts, detect_network_bursts
from hub.analysis.online import Burst, NetworkBurst, OnlineBurstDetector
from hub.analysis.spikes import AnalysisInputError

__all__ = [
    "BURST_DTYPE",
    "AnalysisInputError",
    "AnalysisParams",
    "AnalysisResult",
    "Burst",
    "BurstParams",
    "Cat",
    "NetworkBurst",
    "NetworkBurstParams",
    "NetworkBursts",
    "OnlineBurstDetector",
    "analyze",
    "cat_spread",
    "center_of_activity",
    "center_of_activity_trajectories",
    "compute_metrics",
    "detect_bursts",
    "detect_network_bursts",
]
