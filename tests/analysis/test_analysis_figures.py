"""Every figure is written as non-empty PNG and SVG, or drawn into a given Axes; the report
embeds them."""

import base64
import json

import numpy as np
import pytest
from matplotlib.figure import Figure

from hub.analysis import figures
from hub.analysis.metrics import analyze
from hub.analysis.network_bursts import inter_burst_intervals_ms
from hub.analysis.report import write_report
from hub.analysis.spikes import AnalysisInputError, instantaneous_rate, isi_ms, psth
from tests.analysis.analysis_synth import merge, network_burst, sparse_background

N = 16
X_UM = 50.0 * (np.arange(N) % 4)
Y_UM = 50.0 * (np.arange(N) // 4)
CELL_TYPE = np.array([0, 0, 0, 1] * 4, dtype=np.uint8)


@pytest.fixture(scope="module")
def record():
    bg = sparse_background(N, 20_000.0, rate_hz=3.0)
    nbs = [network_burst(range(10), s, 70.0) for s in (2_000.0, 9_000.0, 15_000.0)]
    ch, t = merge(bg, *nbs)
    res = analyze(ch, t, N, 0.0, 20_000.0, CELL_TYPE, X_UM, Y_UM, stim_ms=[1_950.0])
    return ch, t, res


def _check(paths):
    assert [p.suffix for p in paths] == [".png", ".svg"]
    for p in paths:
        assert p.stat().st_size > 500


@pytest.mark.slow  # every figure, twice
def test_all_figures_write_png_and_svg(tmp_path, record):
    ch, t, res = record
    _check(figures.plot_raster(ch, t, tmp_path / "raster", CELL_TYPE, res.network_bursts))
    v = np.random.default_rng(0).uniform(-70, 30, (3, N))
    _check(figures.plot_potentials(v, (4, 4), tmp_path / "potentials.png", t_ms=[0, 5, 10]))
    pre, post = np.meshgrid(np.arange(N), np.arange(N))
    pre, post = pre.ravel(), post.ravel()
    w = np.random.default_rng(1).uniform(0, 1, pre.size)
    _check(figures.plot_connectivity(pre, post, X_UM, Y_UM, tmp_path / "conn", w, CELL_TYPE))
    _check(
        figures.plot_connectivity(
            pre, post, X_UM, Y_UM, tmp_path / "conn5", w, CELL_TYPE, neuron=5, direction="in"
        )
    )
    series = {
        pop: instantaneous_rate(ch, t, N, 0.0, 20_000.0, 10.0, pop, CELL_TYPE)
        for pop in ("all", "exc", "inh")
    }
    _check(figures.plot_rates(series, tmp_path / "rate"))
    _check(figures.plot_isi_histogram(isi_ms(ch, t), tmp_path / "isi"))
    ibi = inter_burst_intervals_ms(res.network_bursts)
    _check(figures.plot_ibi_histogram(ibi, tmp_path / "ibi"))
    _check(figures.plot_psth(psth(ch, t, [1_950.0], N), tmp_path / "psth"))
    _check(figures.plot_cats(res.cats[:1], X_UM, Y_UM, tmp_path / "cat1", CELL_TYPE, [0, 1]))
    _check(figures.plot_cats(res.cats, X_UM, Y_UM, tmp_path / "cats", CELL_TYPE))


def test_figures_draw_into_a_given_axes_and_handle_empty_data(tmp_path):
    ax = Figure().add_subplot()
    assert figures.plot_raster([], [], ax) == []
    assert len(ax.collections) == 0
    figures.plot_rates({"all": (np.arange(3.0), np.ones(3))}, ax)
    assert len(ax.lines) == 1
    _check(figures.plot_raster([], [], tmp_path / "empty_raster"))
    _check(figures.plot_cats([], X_UM, Y_UM, tmp_path / "no_cats"))
    _check(figures.plot_ibi_histogram([], tmp_path / "no_ibi"))


def test_the_raster_title_names_only_what_it_shows(record):
    ch, t, res = record
    assert len(res.network_bursts.start_ms) > 0
    titles = []
    for cell_type, bursts in ((CELL_TYPE, res.network_bursts), (None, res.network_bursts),
                              (None, None)):  # fmt: skip
        ax = Figure().add_subplot()
        figures.plot_raster(ch, t, ax, cell_type, bursts)
        titles.append(ax.get_title())
    assert titles == [
        "Raster (red excitatory, blue inhibitory; shaded and ▼: network bursts, their cores "
        "darker)",
        "Raster (shaded and ▼: network bursts, their cores darker)",  # an MEA's: no cell type
        "Raster",
    ]


def test_the_raster_draws_the_most_numerous_kind_first_and_the_rarer_on_top():
    # inhibitory cells fire far more often in the default culture: drawn last, their
    # markers (taller than a row of 1,024 channels) would hide the excitatory ones
    cell_type = np.array([0, 0, 0, 1], dtype=np.uint8)
    t = np.arange(0.0, 1_000.0, 10.0)
    ch = np.where(np.arange(t.size) % 10 == 0, 0, 3)  # 10 excitatory spikes, 90 inhibitory
    ax = Figure().add_subplot()
    figures.plot_raster(ch, t, ax, cell_type)
    assert [line.get_color() for line in ax.lines] == [figures.INH_COLOR, figures.EXC_COLOR]
    assert [len(line.get_xdata()) for line in ax.lines] == [90, 10]


def test_figure_input_errors_are_named(tmp_path):
    with pytest.raises(AnalysisInputError, match="rows\\*cols=16"):
        figures.plot_potentials(np.zeros(15), (4, 4), tmp_path / "v")
    with pytest.raises(AnalysisInputError, match="direction"):
        figures.plot_connectivity([0], [1], X_UM, Y_UM, tmp_path / "c", direction="up")
    with pytest.raises(AnalysisInputError, match="formats"):
        figures.plot_rates({}, tmp_path / "r", formats=("jpg",))


def test_report_is_self_contained(tmp_path, record):
    ch, t, res = record
    paths = figures.plot_raster(ch, t, tmp_path / "raster", CELL_TYPE, res.network_bursts)
    paths += figures.plot_cats(res.cats, X_UM, Y_UM, tmp_path / "cats")
    cfg = {"culture": {"n_neurons": N}, "seed": 7}
    out = write_report(
        tmp_path / "run" / "report.html", res.metrics, cfg, paths, timing={"wall_s": 1.5}
    )
    text = out.read_text()
    assert text.count("<img") == 2  # one per figure, PNG preferred over its SVG twin
    png = (tmp_path / "raster.png").read_bytes()
    assert base64.b64encode(png).decode() in text
    assert "mnbr_per_min" in text and "wall_s" in text
    assert json.dumps(cfg, indent=2, sort_keys=True).replace('"', "&quot;") in text
    assert "src='http" not in text and 'src="http' not in text
    with pytest.raises(AnalysisInputError, match="does not exist"):
        write_report(tmp_path / "r.html", {}, {}, [tmp_path / "missing.png"])


def test_report_names_each_protocol_s_figures_and_shows_a_markdown_summary_as_a_table(
    tmp_path, record
):
    ch, t, res = record
    paths = []
    for protocol in ("exc_1", "inh_4"):  # the same figure, one per protocol's folder
        paths += figures.plot_raster(ch, t, tmp_path / protocol / "raster", CELL_TYPE)
    summary = (
        "| measure | paper | NeuVision |\n|---|---|---|\n| MFR (Hz) | 3.41 | **3.03** |\nA note."
    )
    text = write_report(tmp_path / "report.html", {}, {}, paths, summary=summary).read_text()
    assert "<b>exc_1 — raster</b>" in text and "<b>inh_4 — raster</b>" in text
    assert "<th>measure</th>" in text and "<td>3.03</td>" in text and "<p>A note.</p>" in text
    assert "|---|" not in text and "<pre>| measure" not in text


def test_plot_all_writes_the_standard_set(tmp_path, record):
    ch, t, res = record
    paths = figures.plot_all(
        tmp_path / "figs",
        ch,
        t,
        res,
        0.0,
        20_000.0,
        CELL_TYPE,
        X_UM,
        Y_UM,
        stim_channels=[0],
        formats=("png",),
    )
    assert {p.suffix for p in paths} == {".png"}
    stems = sorted({p.stem for p in paths})
    assert stems == sorted(
        [
            "raster",
            "raster_nb",
            "rate",
            "isi",
            "ibi",
            "psth",
            "cat_single",
            "cats_all",
            "cats_evoked",
            "cats_spontaneous",
        ]
    )
    assert all(p.stat().st_size > 500 for p in paths)
