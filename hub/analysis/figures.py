"""Figures of spike-train analysis, one function per figure (matplotlib, no pyplot state).

Every function takes plain arrays and ``out``: either a matplotlib ``Axes`` to draw into (returns
``[]``) or a file path; with a path the figure is written once per format in ``formats`` (PNG and
SVG by default) next to each other, the suffix of ``out`` being replaced, and the list of paths
written is returned. Large scatter layers are rasterised inside SVGs to keep them small.
Robot trajectories are drawn by ``sim_robot.render``, not here.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.colors import to_rgba
from matplotlib.figure import Figure

from hub.analysis.center_of_activity import Cat
from hub.analysis.network_bursts import NetworkBursts, inter_burst_intervals_ms
from hub.analysis.output import save_figure
from hub.analysis.spikes import (
    EXCITATORY,
    INHIBITORY,
    AnalysisInputError,
    Psth,
    check_spikes,
    instantaneous_rate,
    interval_histogram,
    isi_ms,
)

FORMATS = ("png", "svg")
EXC_COLOR = "tab:red"
INH_COLOR = "tab:blue"
OTHER_COLOR = "0.2"
RASTER_KINDS = (EXC_COLOR, INH_COLOR, OTHER_COLOR)
NB_SHADE = "gold"


def _render(
    draw: Callable[[Axes], None], out, figsize=(8.0, 4.0), formats=FORMATS, dpi=120
) -> list[Path]:
    """Draw into ``out`` (an Axes) or into a new figure saved as ``out`` in every format."""
    if isinstance(out, Axes):
        draw(out)
        return []
    fig = Figure(figsize=figsize, layout="constrained")
    ax = fig.add_subplot()
    draw(ax)
    return _save(fig, out, formats, dpi)


def _save(fig: Figure, out, formats, dpi) -> list[Path]:
    base = Path(out)
    if base.suffix.lstrip(".") in FORMATS:
        base = base.with_suffix("")
    base.parent.mkdir(parents=True, exist_ok=True)
    paths = []
    for fmt in formats:
        if fmt not in FORMATS:
            raise AnalysisInputError(f"formats must be among {FORMATS}, got {fmt!r}")
        path = base.with_name(f"{base.name}.{fmt}")
        save_figure(fig, path, format=fmt, dpi=dpi)
        paths.append(path)
    return paths


def _type_colors(channel: np.ndarray, cell_type) -> np.ndarray:
    if cell_type is None:
        return np.full(channel.size, OTHER_COLOR, dtype=object)
    ct = np.asarray(cell_type)[channel]
    colors = np.full(channel.size, OTHER_COLOR, dtype=object)
    colors[ct == EXCITATORY] = EXC_COLOR
    colors[ct == INHIBITORY] = INH_COLOR
    return colors


def plot_raster(
    channel,
    t_ms,
    out,
    cell_type=None,
    network_bursts: NetworkBursts | None = None,
    t_start_ms: float | None = None,
    t_stop_ms: float | None = None,
    formats=FORMATS,
) -> list[Path]:
    """Raster plot: excitatory spikes red, inhibitory blue, network bursts shaded.

    Parameters
    ----------
    channel, t_ms : array_like[k]
        The spikes (sorted by time).
    out : matplotlib Axes or path
        Where to draw (see the module docstring).
    cell_type : uint8[n_channels], optional
        Colours by type; without it every spike is drawn alike.
    network_bursts : NetworkBursts, optional
        Shaded.
    t_start_ms, t_stop_ms : float, optional
        The span shown; default the spikes' span.
    formats : tuple of str
        File formats with a path ``out``.

    Returns
    -------
    list of Path
        The files written (``[]`` when drawing into an Axes).
    """
    ch, t = check_spikes(channel, t_ms)
    lo = t_start_ms if t_start_ms is not None else (t[0] if t.size else 0.0)
    hi = t_stop_ms if t_stop_ms is not None else (t[-1] if t.size else 1.0)
    keep = (t >= lo) & (t <= hi)
    ch, t = ch[keep], t[keep]

    def draw(ax: Axes) -> None:
        if network_bursts is not None:
            nb = network_bursts
            for s, e, cs, ce in zip(nb.start_ms, nb.end_ms, nb.core_start_ms, nb.core_end_ms,
                                    strict=True):  # fmt: skip
                if e >= lo and s <= hi:  # the extent pale, the core strong: in a closed
                    # loop a stimulated channel's burst of seconds stretches the extent
                    ax.axvspan(s / 1000.0, e / 1000.0, fc=NB_SHADE, ec="none", alpha=0.12)
                    # an edge line keeps short cores visible when zoomed out
                    ax.axvspan(cs / 1000.0, ce / 1000.0, fc=NB_SHADE, ec=NB_SHADE, alpha=0.45,
                               lw=0.8)  # fmt: skip
            # A marker above each core: visible at any time scale (a 50 ms burst is a
            # hairline in a 60 s raster).
            mid_s = (np.asarray(nb.core_start_ms) + np.asarray(nb.core_end_ms)) / 2e3
            shown = mid_s[(mid_s >= lo / 1e3) & (mid_s <= hi / 1e3)]
            top = (ch.max() if ch.size else 1) * 1.04 + 1
            ax.plot(shown, np.full(shown.size, top), ls="none", marker="v", ms=6,
                    color=NB_SHADE, mec="0.3", mew=0.5, clip_on=False)  # fmt: skip
        colors = _type_colors(ch, cell_type)
        # dense rasters (long records) use pixel markers: faster and less over-plotting
        marker, size = ("|", 2.0) if t.size < 200_000 else (",", 1.0)
        # The most numerous kind first: a marker is taller than a row of a large culture,
        # and the culture's few fast-spiking cells would otherwise hide the rest.
        kinds = [(int((colors == c).sum()), i, c) for i, c in enumerate(RASTER_KINDS)]
        for count, _, color in sorted(kinds, key=lambda kind: (-kind[0], kind[1])):
            sel = colors == color
            if count:
                ax.plot(
                    t[sel] / 1000.0,
                    ch[sel],
                    ls="none",
                    marker=marker,
                    ms=size,
                    mew=0.6,
                    color=color,
                    rasterized=True,
                )
        ax.set_xlim(lo / 1000.0, hi / 1000.0 if hi > lo else lo / 1000.0 + 1.0)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("channel")
        ax.set_title(_raster_title(colors, network_bursts, lo, hi))

    return _render(draw, out, figsize=(10.0, 5.0), formats=formats)


def _raster_title(
    colors: np.ndarray, network_bursts: NetworkBursts | None, lo_ms: float, hi_ms: float
) -> str:
    """The raster's title, naming only what it shows: an MEA's channels have no cell type,
    and a raster with no network burst in its span ``[lo_ms, hi_ms]`` has nothing shaded."""
    keys = []
    if (colors != OTHER_COLOR).any():
        keys.append("red excitatory, blue inhibitory")
    nbs = network_bursts
    if nbs is not None and ((nbs.start_ms <= hi_ms) & (nbs.end_ms >= lo_ms)).any():
        keys.append("shaded and ▼: network bursts, their cores darker")
    return "Raster" + (f" ({'; '.join(keys)})" if keys else "")


def plot_potentials(
    v_mv, grid_shape: tuple[int, int], out, t_ms=None, vmin_mv=-80.0, vmax_mv=30.0, formats=FORMATS
) -> list[Path]:
    """Membrane-potential snapshots on the grid.

    Parameters
    ----------
    v_mv : float array, shape (n,) or (k, n)
        One or k snapshots, ``n = rows * cols`` in row-major grid order.
    grid_shape : (rows, cols)
    t_ms : float array_like[k], optional
        Labels each snapshot.
    vmin_mv, vmax_mv : float
        The colour scale.
    out : matplotlib Axes or path
        Where to draw (see the module docstring).
    formats : tuple of str
        File formats with a path ``out``.

    Returns
    -------
    list of Path
        The files written (``[]`` when drawing into an Axes).
    """
    v = np.atleast_2d(np.asarray(v_mv, dtype=np.float64))
    rows, cols = grid_shape
    if v.ndim != 2 or v.shape[1] != rows * cols:
        raise AnalysisInputError(
            f"v_mv must have rows*cols={rows * cols} values per snapshot, got shape {v.shape}"
        )
    k = v.shape[0]
    times = np.asarray(t_ms, dtype=np.float64).ravel() if t_ms is not None else None
    if times is not None and times.size != k:
        raise AnalysisInputError(f"t_ms must have one time per snapshot ({k}), got {times.size}")

    def draw_one(ax: Axes, i: int):
        im = ax.imshow(
            v[i].reshape(rows, cols), vmin=vmin_mv, vmax=vmax_mv, cmap="viridis", origin="lower"
        )
        ax.set_xticks([])
        ax.set_yticks([])
        if times is not None:
            ax.set_title(f"{times[i]:.0f} ms", fontsize=9)
        return im

    if isinstance(out, Axes):
        if k != 1:
            raise AnalysisInputError(f"an Axes takes one snapshot, got {k}")
        draw_one(out, 0)
        return []
    fig = Figure(figsize=(2.0 * k + 1.0, 2.4), layout="constrained")
    axes = fig.subplots(1, k, squeeze=False)[0]
    im = None
    for i, ax in enumerate(axes):
        im = draw_one(ax, i)
    fig.colorbar(im, ax=list(axes), label="membrane potential (mV)", shrink=0.8)
    return _save(fig, out, formats, 120)


def plot_connectivity(
    pre,
    post,
    x_um,
    y_um,
    out,
    weight=None,
    cell_type=None,
    neuron: int | None = None,
    direction: str = "both",
    max_links: int = 20_000,
    formats=FORMATS,
) -> list[Path]:
    """Connections drawn as lines: colour by the presynaptic type (red exc, blue inh),
    transparency by |weight|. With ``neuron``, only its inputs (``direction="in"``), outputs
    (``"out"``) or both. Above ``max_links`` links an evenly spaced subset is drawn.

    Parameters
    ----------
    pre, post : int array_like[m]
        Each link's presynaptic and postsynaptic neuron.
    x_um, y_um : float array_like[n_neurons]
        The neurons' positions.
    out : matplotlib Axes or path
        Where to draw (see the module docstring).
    weight : float array_like[m], optional
        Each link's weight; without it every link is drawn alike.
    cell_type : uint8[n_neurons], optional
        Colours by type; without it every link is drawn alike.
    neuron : int, optional
        Draw only this neuron's links, and ring it.
    direction : {"in", "out", "both"}
        Which of ``neuron``'s links.
    max_links : int
        The most links drawn.
    formats : tuple of str
        File formats with a path ``out``.

    Returns
    -------
    list of Path
        The files written (``[]`` when drawing into an Axes).

    Raises
    ------
    AnalysisInputError
        ``pre``, ``post`` and ``weight`` differ in shape, or ``direction`` is none of the three.
    """
    pre = np.asarray(pre, dtype=np.int64)
    post = np.asarray(post, dtype=np.int64)
    x = np.asarray(x_um, dtype=np.float64)
    y = np.asarray(y_um, dtype=np.float64)
    if pre.shape != post.shape:
        raise AnalysisInputError(f"pre and post must match, got {pre.shape} and {post.shape}")
    w = np.ones(pre.size) if weight is None else np.abs(np.asarray(weight, dtype=np.float64))
    if w.shape != pre.shape:
        raise AnalysisInputError(f"weight must match pre, got {w.shape} and {pre.shape}")
    if direction not in ("in", "out", "both"):
        raise AnalysisInputError(f"direction must be 'in', 'out' or 'both', got {direction!r}")
    if neuron is not None:
        sel = np.zeros(pre.size, dtype=bool)
        if direction in ("in", "both"):
            sel |= post == neuron
        if direction in ("out", "both"):
            sel |= pre == neuron
        pre, post, w = pre[sel], post[sel], w[sel]
    if pre.size > max_links:
        pick = np.linspace(0, pre.size - 1, max_links).round().astype(np.int64)
        pre, post, w = pre[pick], post[pick], w[pick]

    def draw(ax: Axes) -> None:
        if pre.size:
            rgba = np.array([to_rgba(c) for c in _type_colors(pre, cell_type)], dtype=float)
            wmax = w.max() if w.max() > 0 else 1.0
            rgba[:, 3] = 0.05 + 0.75 * (w / wmax)
            segs = np.stack(
                [np.column_stack([x[pre], y[pre]]), np.column_stack([x[post], y[post]])], 1
            )
            ax.add_collection(LineCollection(segs, colors=rgba, linewidths=0.6))
        node_colors = _type_colors(np.arange(x.size), cell_type)
        ax.scatter(x, y, s=6, c=list(node_colors), zorder=3)
        if neuron is not None:
            ax.scatter([x[neuron]], [y[neuron]], s=60, facecolors="none", edgecolors="k", zorder=4)
        ax.set_aspect("equal")
        ax.autoscale_view()
        ax.set_xlabel("x (µm)")
        ax.set_ylabel("y (µm)")
        what = "all links" if neuron is None else f"neuron {neuron}: {direction}"
        ax.set_title(f"Connectivity ({what}; {pre.size} drawn)")

    return _render(draw, out, figsize=(6.5, 6.0), formats=formats)


def plot_rates(series: dict, out, formats=FORMATS) -> list[Path]:
    """Instantaneous rate curves.

    Parameters
    ----------
    series : dict
        Maps a label (``"all"``, ``"exc"``, ``"inh"``, …) to ``(centers_ms, rate_hz)`` as
        returned by ``spikes.instantaneous_rate``.
    out : matplotlib Axes or path
        Where to draw (see the module docstring).
    formats : tuple of str
        File formats with a path ``out``.

    Returns
    -------
    list of Path
        The files written (``[]`` when drawing into an Axes).
    """
    colors = {"all": OTHER_COLOR, "exc": EXC_COLOR, "inh": INH_COLOR}

    def draw(ax: Axes) -> None:
        for label, (t, r) in series.items():
            ax.plot(np.asarray(t) / 1000.0, r, lw=0.8, label=label, color=colors.get(label))
        ax.set_xlabel("time (s)")
        ax.set_ylabel("rate (spikes/s, channels summed)")
        ax.set_title("Instantaneous spiking rate of the population")
        if series:
            ax.legend(loc="upper right")

    return _render(draw, out, figsize=(10.0, 3.5), formats=formats)


def plot_histogram(
    counts, edges, out, title: str, xlabel: str, ylabel: str = "count", formats=FORMATS
) -> list[Path]:
    """A histogram from counts and bin edges (the shared base of ISI/IBI/PSTH).

    Parameters
    ----------
    counts : array_like[n_bins]
    edges : array_like[n_bins + 1]
    title, xlabel, ylabel : str
    out : matplotlib Axes or path
        Where to draw (see the module docstring).
    formats : tuple of str
        File formats with a path ``out``.

    Returns
    -------
    list of Path
        The files written (``[]`` when drawing into an Axes).
    """
    counts = np.asarray(counts)
    edges = np.asarray(edges, dtype=np.float64)
    if edges.size != counts.size + 1:
        raise AnalysisInputError(
            f"edges must have len(counts)+1={counts.size + 1} entries, got {edges.size}"
        )

    def draw(ax: Axes) -> None:
        ax.stairs(counts, edges, fill=True, color="tab:red", alpha=0.8)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.set_title(title)

    return _render(draw, out, figsize=(6.0, 3.5), formats=formats)


def plot_isi_histogram(isi, out, bin_ms=1.0, max_ms=200.0, formats=FORMATS) -> list[Path]:
    """ISI histogram.

    Parameters
    ----------
    isi : float array_like
        Intervals (ms) from ``spikes.isi_ms``.
    bin_ms, max_ms : float
        Bins on ``[0, max_ms]``.
    out : matplotlib Axes or path
        Where to draw (see the module docstring).
    formats : tuple of str
        File formats with a path ``out``.

    Returns
    -------
    list of Path
        The files written (``[]`` when drawing into an Axes).
    """
    counts, edges = interval_histogram(isi, bin_ms, max_ms)
    return plot_histogram(counts, edges, out, "Inter-spike intervals", "ISI (ms)", formats=formats)


def plot_ibi_histogram(ibi, out, bin_ms=500.0, max_ms=None, formats=FORMATS) -> list[Path]:
    """IBI histogram (intervals between network-burst starts), in seconds on the axis.

    Parameters
    ----------
    ibi : float array_like
        Intervals (ms) from ``network_bursts.inter_burst_intervals_ms``.
    bin_ms : float
    max_ms : float, optional
        Default the longest interval plus one bin.
    out : matplotlib Axes or path
        Where to draw (see the module docstring).
    formats : tuple of str
        File formats with a path ``out``.

    Returns
    -------
    list of Path
        The files written (``[]`` when drawing into an Axes).
    """
    ibi = np.asarray(ibi, dtype=np.float64)
    top = max_ms if max_ms is not None else (float(ibi.max()) + bin_ms if ibi.size else bin_ms)
    counts, edges = interval_histogram(ibi, bin_ms, top)
    return plot_histogram(
        counts, edges / 1000.0, out, "Inter-network-burst intervals", "IBI (s)", formats=formats
    )


def plot_psth(h: Psth, out, formats=FORMATS) -> list[Path]:
    """PSTH as mean rate per channel, with the stimulus at 0 ms.

    Parameters
    ----------
    h : Psth
        From ``spikes.psth``.
    out : matplotlib Axes or path
        Where to draw (see the module docstring).
    formats : tuple of str
        File formats with a path ``out``.

    Returns
    -------
    list of Path
        The files written (``[]`` when drawing into an Axes).
    """

    def draw(ax: Axes) -> None:
        ax.stairs(h.rate_hz, h.edges_ms, fill=True, color="tab:red", alpha=0.8)
        ax.axvline(0.0, color="k", lw=0.8, ls="--")
        ax.set_xlabel("time after stimulus (ms)")
        ax.set_ylabel("rate per channel (spikes/s)")
        ax.set_title(f"PSTH ({h.n_stimuli} stimuli, {h.n_channels} channels)")

    return _render(draw, out, figsize=(6.0, 3.5), formats=formats)


def plot_cats(
    cats: list[Cat],
    x_um,
    y_um,
    out,
    cell_type=None,
    stim_channels=None,
    title: str | None = None,
    formats=FORMATS,
) -> list[Path]:
    """One CAT (coloured by time) or many superimposed (thin lines) on the culture map.

    Channel positions are drawn as small dots (red exc, blue inh); ``stim_channels`` are
    ringed; each CAT's first point is a black dot.

    Parameters
    ----------
    cats : list of Cat
        The trajectories (empty ones are left out).
    x_um, y_um : float array_like[n_channels]
        Channel positions.
    out : matplotlib Axes or path
        Where to draw (see the module docstring).
    cell_type : uint8[n_channels], optional
        Colours the channels by type.
    stim_channels : int array_like, optional
        Channels to ring as stimulated.
    title : str, optional
        Default: the number of trajectories drawn.
    formats : tuple of str
        File formats with a path ``out``.

    Returns
    -------
    list of Path
        The files written (``[]`` when drawing into an Axes).
    """
    x = np.asarray(x_um, dtype=np.float64)
    y = np.asarray(y_um, dtype=np.float64)

    def draw(ax: Axes) -> None:
        colors = _type_colors(np.arange(x.size), cell_type)
        ax.scatter(x, y, s=4, c=list(colors), alpha=0.35, rasterized=True)
        if stim_channels is not None:
            sc = np.asarray(stim_channels, dtype=np.int64)
            ax.scatter(x[sc], y[sc], s=80, facecolors="none", edgecolors="k", lw=1.5)
        nonempty = [c for c in cats if len(c)]
        if len(nonempty) == 1:
            c = nonempty[0]
            ax.plot(c.x_um, c.y_um, color="0.3", lw=1.0)
            sc_ = ax.scatter(c.x_um, c.y_um, c=c.t_ms - c.t_ms[0], cmap="plasma", s=18, zorder=3)
            ax.figure.colorbar(sc_, ax=ax, label="time from burst start (ms)", shrink=0.8)
        else:
            for c in nonempty:
                ax.plot(c.x_um, c.y_um, lw=0.7, alpha=0.5)
        for c in nonempty:
            ax.plot(c.x_um[0], c.y_um[0], "o", color="k", ms=3, zorder=4)
        ax.set_aspect("equal")
        ax.set_xlabel("x (µm)")
        ax.set_ylabel("y (µm)")
        ax.set_title(title or f"Center of activity trajectories ({len(nonempty)})")

    return _render(draw, out, figsize=(6.5, 6.0), formats=formats)


def plot_all(
    out_dir,
    channel,
    t_ms,
    result,
    t_start_ms: float,
    t_stop_ms: float,
    cell_type=None,
    x_um=None,
    y_um=None,
    stim_channels=None,
    raster_span_ms: float = 60_000.0,
    rate_bin_ms: float = 10.0,
    formats=FORMATS,
) -> list[Path]:
    """The standard figure set of one analysed record (``metrics.analyze``'s ``result``).

    Writes into ``out_dir``: ``raster`` (the first ``raster_span_ms``), ``raster_nb`` (1 s around
    the first network burst), ``rate`` (all/exc/inh), ``isi``, ``ibi``, and when available
    ``psth``, ``cat_single``, ``cats_all``, ``cats_evoked``, ``cats_spontaneous``.

    Parameters
    ----------
    out_dir : str or Path
        The folder written into.
    channel, t_ms : array_like[k]
        The analysed spikes (channel indices, sorted times).
    result : AnalysisResult
        From `metrics.analyze` of those spikes.
    t_start_ms, t_stop_ms : float
        The analysed span.
    cell_type : uint8[n_channels], optional
    x_um, y_um : float[n_channels], optional
        Channel positions (the CAT figures).
    stim_channels : int array, optional
        Channels marked as stimulated in the CAT figures.
    raster_span_ms : float
        Length of the ``raster`` figure.
    rate_bin_ms : float
        Bin of the ``rate`` figure.
    formats : tuple of str
        File formats.

    Returns
    -------
    list of Path
        Every file written, in the order above.
    """
    out = Path(out_dir)
    ch, t = check_spikes(channel, t_ms)
    n_channels = result.rates_hz.size
    nbs = result.network_bursts
    paths: list[Path] = []
    raster_stop = min(t_stop_ms, t_start_ms + raster_span_ms)
    paths += plot_raster(ch, t, out / "raster", cell_type, nbs, t_start_ms, raster_stop, formats)
    if len(nbs):
        s = nbs.start_ms[0]
        paths += plot_raster(
            ch,
            t,
            out / "raster_nb",
            cell_type,
            nbs,
            max(s - 300.0, t_start_ms),
            s + 700.0,
            formats,
        )
    pops = ("all", "exc", "inh") if cell_type is not None else ("all",)
    series = {
        pop: instantaneous_rate(
            ch, t, n_channels, t_start_ms, raster_stop, rate_bin_ms, pop, cell_type
        )
        for pop in pops
    }
    paths += plot_rates(series, out / "rate", formats)
    paths += plot_isi_histogram(isi_ms(ch, t), out / "isi", formats=formats)
    paths += plot_ibi_histogram(inter_burst_intervals_ms(nbs), out / "ibi", formats=formats)
    if result.psth is not None:
        paths += plot_psth(result.psth, out / "psth", formats)
    if result.cats and x_um is not None and y_um is not None:
        cats = result.cats
        longest = int(np.argmax([len(c) for c in cats]))
        paths += plot_cats(
            [cats[longest]],
            x_um,
            y_um,
            out / "cat_single",
            cell_type,
            stim_channels,
            f"CAT of network burst {longest}",
            formats,
        )
        paths += plot_cats(
            cats,
            x_um,
            y_um,
            out / "cats_all",
            cell_type,
            stim_channels,
            f"All CATs ({len(cats)})",
            formats,
        )
        if result.evoked is not None:
            for name, keep in (("evoked", result.evoked), ("spontaneous", ~result.evoked)):
                chosen = [c for c, k in zip(cats, keep, strict=True) if k]
                paths += plot_cats(
                    chosen,
                    x_um,
                    y_um,
                    out / f"cats_{name}",
                    cell_type,
                    stim_channels,
                    f"CATs of {name} network bursts ({len(chosen)})",
                    formats,
                )
    return paths
