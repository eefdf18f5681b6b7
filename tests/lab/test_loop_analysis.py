"""``analyze`` on a closed-loop run: the loop's figures, and no PSTH over every step."""

from __future__ import annotations

import numpy as np
import pytest

from hub.analysis.metrics import AnalysisParams
from lab.loop_figure import loop_series
from lab.run_analysis import analyze_run, psth_applies
from neuvision import Experiment


def test_a_psth_needs_stimuli_further_apart_than_its_window():
    params = AnalysisParams()  # a 0-300 ms window
    assert psth_applies(np.arange(0.0, 10_000.0, 1000.0), params) == ""
    assert psth_applies(None, params) == ""
    why = psth_applies(np.arange(0.0, 1000.0, 10.0), params)
    assert "every 10 ms" in why and "300 ms" in why


@pytest.mark.slow
@pytest.mark.bus
def test_a_closed_loop_run_gets_the_loop_figure_and_no_psth(tmp_path):
    run = Experiment("configs/closed_loop.toml", {"experiment.duration_s": 2.0}).run(tmp_path)
    result = analyze_run(run.run_dir)
    names = {p.name for p in result["figures"]}
    assert {"loop.png", "stimulation_sites.png", "trajectory.png", "raster.png"} <= names
    assert "psth.png" not in names
    metrics = result["metrics"]
    assert (
        "psth_peak_ms" not in metrics
        and "closer than the PSTH window" in metrics["psth_not_computed"]
    )
    assert metrics["n_stimuli"] == 199  # every step but the first
    series = loop_series(run.record)
    assert series.ranges_m.shape == (200, 7) and series.wheels_mps.shape == (201, 2)
    assert series.ca_t_s.size == 200 and np.all(series.ca_distance_frac[1:] <= 1.5)
    assert series.pulse_t_s.size == run.stimulation["t_ms"].size


def test_the_ca_is_drawn_from_the_decoders_running_centre_when_it_has_one():
    # decoding.params.centre_tau_s > 0: the decoder steers by the CA's departure from its
    # own running mean, which moves `follow` of the way at each step with spikes
    from lab.loop_figure import _running_centre

    dx = np.array([10.0, 10.0, np.nan, 10.0])  # a CA held off-centre; no spike at step 2
    rx, ry = _running_centre(dx, np.zeros(4), follow=0.1)
    assert rx[[0, 1, 3]] == pytest.approx([10.0, 9.0, 8.1])  # the centre catches up
    assert np.isnan(rx[2]) and ry[[0, 1, 3]] == pytest.approx([0.0, 0.0, 0.0])
