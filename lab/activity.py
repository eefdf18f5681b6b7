"""Activity figures of a simulated culture, computed by ``hub.analysis`` (the project's one
definition of bursts, network bursts and their statistics; see ``docs/analysis.md``).

This is the adapter that calibration and reproduction (``lab.calibrate``, ``lab.reproduce``)
use to hand neuron-level spikes and the grid layout to ``hub.analysis``. It lives in the lab
layer because it joins the two: the simulator never imports ``hub``, and ``hub`` never imports
the simulator.
"""

from __future__ import annotations

from hub.analysis.metrics import AnalysisParams, AnalysisResult, analyze
from sim_network.layout import Layout
from sim_network.records import Spikes


def analyze_culture(
    spikes: Spikes,
    layout: Layout,
    t0_ms: float,
    t1_ms: float,
    stim_ms=None,
    params: AnalysisParams | None = None,
) -> AnalysisResult:
    """Full ``hub.analysis.analyze`` of neuron-level spikes in ``[t0_ms, t1_ms)``.

    Parameters
    ----------
    spikes : sim_network.Spikes
        Neuron-level (``Network.neuron_spikes``): channels are neuron indices.
    layout : sim_network.layout.Layout
        Cell types and positions of the neurons.
    t0_ms, t1_ms : float
        The analysed span.
    stim_ms : float array, optional
        Pulse onsets (absolute ms): enables the PSTH and the evoked / spontaneous split.
    params : AnalysisParams, optional

    Returns
    -------
    AnalysisResult
    """
    return analyze(
        spikes.channel,
        spikes.t_ms,
        layout.n,
        t0_ms,
        t1_ms,
        cell_type=layout.cell_type,
        x_um=layout.x_um,
        y_um=layout.y_um,
        stim_ms=stim_ms,
        params=params,
    )


def summarize(spikes: Spikes, layout: Layout, t0_ms: float, t1_ms: float, stim_ms=None) -> dict:
    """The metrics dict of `analyze_culture`.

    Parameters
    ----------
    spikes, layout, t0_ms, t1_ms, stim_ms
        As for `analyze_culture`.

    Returns
    -------
    dict
        ``hub.analysis.metrics`` keys.
    """
    return analyze_culture(spikes, layout, t0_ms, t1_ms, stim_ms).metrics
