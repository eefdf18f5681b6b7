"""The closed loop of a recorded run in pictures: what the robot sensed, where the culture was
stimulated, where its Center of Activity went and how the wheels were driven.

:func:`loop_series` reads the arrays from a record (plain data); :func:`plot_loop` draws
them on one time axis; :func:`plot_stimulation_sites` maps the stimulated electrodes on the
culture.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from hub.analysis.figures import FORMATS
from hub.analysis.output import save_figure
from hub.coding import CultureFrame
from hub.decoding import WINDOW_MS
from hub.protocol import MotorCommand, SensorReading, SpikeBatch, Stimulation
from hub.record import DATA_DIRECTIONS, RunRecord


@dataclass(frozen=True)
class LoopSeries:
    """A run's loop as arrays (times in run time; steps in order)."""

    sensor_t_s: np.ndarray  # [n]
    ranges_m: np.ndarray  # [n, sensors]
    max_range_m: float
    pulse_t_s: np.ndarray  # [p] every pulse's onset
    pulse_channel: np.ndarray  # [p]
    pulse_amplitude_ua: np.ndarray  # [p]
    ca_t_s: np.ndarray  # [m] the end of each culture step
    ca_distance_frac: np.ndarray  # [m] CA's distance from the culture's centre / its radius
    ca_angle_deg: np.ndarray  # [m] CA's angle, counter-clockwise from the culture's +y
    wheel_t_s: np.ndarray  # [w] each motor command's step start
    wheels_mps: np.ndarray  # [w, 2] left, right


def loop_series(
    rec: RunRecord, ca_window_ms: float = WINDOW_MS, centre_tau_s: float = 0.0
) -> LoopSeries:
    """The loop's arrays from a record, the Center of Activity (CA) as the decoder computes it.

    Parameters
    ----------
    rec : RunRecord
        The run.
    ca_window_ms : float
        The window, ending at each culture step's end, whose spikes give the CA.
    centre_tau_s : float
        0: the CA from the culture's geometric centre (the paper); > 0: from the decoder's
        running mean of the CA (``decoding.params.centre_tau_s``,
        :func:`hub.decoding.center_of_activity`).
    """
    readings = sorted(rec.decoded(SensorReading, *DATA_DIRECTIONS), key=lambda r: r.step)
    body = rec.descriptions().get("body")
    culture = rec.descriptions().get("culture")
    n_sensors = readings[0].ranges_m.size if readings else 0
    stims = rec.decoded(Stimulation, "tx")
    pulse_t = [s.t0_s + np.asarray(s.onset_ms, np.float64) / 1e3 for s in stims]
    pulse_c = [np.asarray(s.channel) for s in stims]
    pulse_a = [np.asarray(s.amplitude_ua, np.float64) for s in stims]
    motors = sorted(rec.decoded(MotorCommand, "tx"), key=lambda m: m.step)
    ca_t, ca_d, ca_a = _center_of_activity(rec, culture, ca_window_ms, centre_tau_s)
    return LoopSeries(
        sensor_t_s=np.array([r.t_s for r in readings], np.float64),
        ranges_m=np.array([r.ranges_m for r in readings], np.float64).reshape(-1, n_sensors),
        max_range_m=float(body.max_range_m) if body is not None else 1.0,
        pulse_t_s=np.concatenate(pulse_t) if pulse_t else np.zeros(0),
        pulse_channel=np.concatenate(pulse_c) if pulse_c else np.zeros(0, np.uint32),
        pulse_amplitude_ua=np.concatenate(pulse_a) if pulse_a else np.zeros(0),
        ca_t_s=ca_t,
        ca_distance_frac=ca_d,
        ca_angle_deg=ca_a,
        wheel_t_s=np.array([m.t0_s for m in motors], np.float64),
        wheels_mps=np.array([(m.left_mps, m.right_mps) for m in motors]).reshape(-1, 2),
    )


def _center_of_activity(rec: RunRecord, culture, window_ms: float, centre_tau_s: float):
    """Spike-weighted mean electrode position over a trailing window at each step's end,
    from the culture's centre (or the decoder's running one: :func:`_running_centre`)."""
    empty = (np.zeros(0), np.zeros(0), np.zeros(0))
    if culture is None or culture.x_um is None:
        return empty
    channel, t_ms = rec.spikes()  # in time order
    ids = np.asarray(culture.channel, np.int64)
    sort = np.argsort(ids)
    pos = np.minimum(np.searchsorted(ids[sort], channel), ids.size - 1)
    known = ids[sort][pos] == channel
    index = sort[pos][known]
    t_ms = t_ms[known]
    x, y = np.asarray(culture.x_um, np.float64), np.asarray(culture.y_um, np.float64)
    frame = CultureFrame.of(culture)  # the decoder's centre and radius
    cx, cy, radius = frame.centre_x_um, frame.centre_y_um, frame.radius_um
    ends_ms = np.unique([b.t1_s * 1e3 for b in rec.decoded(SpikeBatch, *DATA_DIRECTIONS)])
    if ends_ms.size == 0:
        return empty
    cum_x = np.concatenate([[0.0], np.cumsum(x[index] - cx)])
    cum_y = np.concatenate([[0.0], np.cumsum(y[index] - cy)])
    hi = np.searchsorted(t_ms, ends_ms, side="left")
    lo = np.searchsorted(t_ms, ends_ms - window_ms, side="left")
    n = hi - lo
    with np.errstate(invalid="ignore", divide="ignore"):
        dx = (cum_x[hi] - cum_x[lo]) / n
        dy = (cum_y[hi] - cum_y[lo]) / n
    if centre_tau_s > 0 and ends_ms.size > 1:
        period_s = float(np.median(np.diff(ends_ms))) / 1e3
        dx, dy = _running_centre(dx, dy, min(1.0, period_s / centre_tau_s))
    distance = np.hypot(dx, dy) / radius
    angle = np.degrees(np.arctan2(-dx, dy))  # counter-clockwise from +y: -x is to the left
    return ends_ms / 1e3, distance, angle


def _running_centre(dx: np.ndarray, dy: np.ndarray, follow: float):
    """The CA from the decoder's running centre (:func:`hub.decoding.center_of_activity`
    with ``centre_tau_s``): the centre starts at the culture's and moves ``follow`` of the
    way to the CA at each step whose window has spikes (NaN: none)."""
    rx, ry = np.full(dx.size, np.nan), np.full(dy.size, np.nan)
    centre_x = centre_y = 0.0
    for i in np.flatnonzero(np.isfinite(dx)):
        rx[i], ry[i] = dx[i] - centre_x, dy[i] - centre_y
        centre_x += follow * rx[i]
        centre_y += follow * ry[i]
    return rx, ry


def plot_loop(
    series: LoopSeries,
    out: str | Path,
    title: str = "",
    ca_window_ms: float = WINDOW_MS,
    centre_tau_s: float = 0.0,
) -> list[Path]:
    """Four panels on one time axis: sensor ranges, pulses by channel (amplitude as
    colour), the CA's distance and angle, the wheel speeds. Returns the files written.

    Parameters
    ----------
    series : LoopSeries
        From :func:`loop_series`.
    out : path
        The files' path without its suffix: one file per format of
        :data:`hub.analysis.figures.FORMATS`.
    title : str
        Above the panels; "" for none.
    ca_window_ms, centre_tau_s : float
        Those ``series`` was made with, for the CA panel's title.
    """
    fig = Figure(figsize=(11, 9), layout="constrained")
    axes = fig.subplots(4, 1, sharex=True)
    ax = axes[0]
    if series.ranges_m.size:
        n_sensors = series.ranges_m.shape[1]
        extent = (series.sensor_t_s[0], series.sensor_t_s[-1], -0.5, n_sensors - 0.5)
        im = ax.imshow(
            series.ranges_m.T,
            aspect="auto",
            origin="lower",
            extent=extent,
            cmap="viridis",
            vmin=0,
            vmax=series.max_range_m,
            interpolation="nearest",
        )
        fig.colorbar(im, ax=ax, label="range (m)")
    ax.set_ylabel("sensor")
    ax.set_title("Sensor ranges (the body's range finders; bright: nothing near)")
    ax = axes[1]
    if series.pulse_t_s.size:
        sc = ax.scatter(series.pulse_t_s, series.pulse_channel, c=series.pulse_amplitude_ua,
                        s=4, marker="|", cmap="magma_r", rasterized=True)  # fmt: skip
        fig.colorbar(sc, ax=ax, label="amplitude (µA)")
    ax.set_ylabel("channel")
    ax.set_title("Stimulation: each pulse sent, by channel (coded from the sensors)")
    ax = axes[2]
    ax.plot(series.ca_t_s, series.ca_distance_frac, lw=0.8, color="tab:purple")
    ax.set_ylabel("CA distance\n(× culture radius)", color="tab:purple")
    twin = ax.twinx()
    twin.plot(series.ca_t_s, series.ca_angle_deg, lw=0.6, color="tab:orange", alpha=0.8)
    twin.set_ylabel("CA angle (deg, + left)", color="tab:orange")
    centre = (
        f"the decoder's running centre (its mean over ~{centre_tau_s:g} s)"
        if centre_tau_s > 0
        else "the culture's geometric centre"
    )
    ax.set_title(f"Center of Activity over the last {ca_window_ms:g} ms, from {centre}")
    ax = axes[3]
    if series.wheels_mps.size:
        ax.step(series.wheel_t_s, series.wheels_mps[:, 0], where="post", lw=0.8, label="left")
        ax.step(series.wheel_t_s, series.wheels_mps[:, 1], where="post", lw=0.8, label="right")
        ax.legend(loc="upper right", fontsize="small")
    ax.set_ylabel("wheel speed (m/s)")
    ax.set_xlabel("run time (s)")
    ax.set_title("Wheel commands (decoded from the culture's spikes)")
    if title:
        fig.suptitle(title)
    return _save(fig, Path(out))


def plot_stimulation_sites(rec: RunRecord, series: LoopSeries, out: str | Path) -> list[Path]:
    """The culture's electrodes, the stimulated ones sized and coloured by pulses received.

    Parameters
    ----------
    rec : RunRecord
        The run: its culture's description gives the electrodes' positions.
    series : LoopSeries
        Its pulses (:func:`loop_series`).
    out : path
        As for :func:`plot_loop`.

    Returns
    -------
    list of Path
        The files written; none when the culture has no positions or no pulse was sent.
    """
    culture = rec.descriptions().get("culture")
    if culture is None or culture.x_um is None or series.pulse_channel.size == 0:
        return []
    ids, counts = np.unique(series.pulse_channel, return_counts=True)
    where = {int(c): i for i, c in enumerate(np.asarray(culture.channel))}
    sel = np.array([where[int(c)] for c in ids if int(c) in where], dtype=np.int64)
    counts = np.array([n for c, n in zip(ids, counts, strict=True) if int(c) in where])
    if sel.size == 0:  # no pulse on a channel the culture described: no site to show
        return []
    fig = Figure(figsize=(6.5, 5.5), layout="constrained")
    ax = fig.subplots()
    x, y = np.asarray(culture.x_um), np.asarray(culture.y_um)
    ax.scatter(x, y, s=4, color="0.8", label="electrodes")
    sc = ax.scatter(x[sel], y[sel], s=20 + 80 * counts / counts.max(), c=counts, cmap="plasma")
    fig.colorbar(sc, ax=ax, label="pulses received")
    ax.set_aspect("equal")
    ax.set_xlabel("x (µm)")
    ax.set_ylabel("y (µm)")
    ax.set_title("Stimulation sites on the culture")
    return _save(fig, Path(out))


def _save(fig, out: Path) -> list[Path]:
    paths = []
    for fmt in FORMATS:
        path = out.with_suffix(f".{fmt}")
        save_figure(fig, path, dpi=120)
        paths.append(path)
    return paths
