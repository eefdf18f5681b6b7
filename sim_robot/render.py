"""Pictures of a world and of a trajectory (matplotlib, headless: no pyplot, no GUI)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Polygon, Rectangle

from .world import World

WALL_COLOR = "0.2"
OBSTACLE_COLOR = "#b0b0b0"
ROBOT_COLOR = "#1f77b4"
RAY_COLOR = "#d62728"
# The path is drawn through a point each time the robot has travelled this far: below a
# pixel at the figure's size (a 1 m arena ~ 1 mm a pixel at 150 dpi), and a long run's
# figure stays small (one segment a step made a 10,000 s lockstep run's SVG 110 MB).
PATH_STEP_M = 0.0005


def draw_world(world: World, ax, pose=None, ranges=None) -> None:
    """Draw walls and obstacles on ``ax``; with ``pose``, the robot; with ``ranges``, its rays.

    Parameters
    ----------
    world : World
    ax : matplotlib Axes
    pose : (x_m, y_m, heading_rad), optional
    ranges : float[n_sensors], optional
        Range finder readings (m) drawn as rays from each sensor; rays that hit are solid,
        those at ``max_range_m`` dotted.
    """
    a = world.arena
    if a.shape == "circle":
        ax.add_patch(Circle((0, 0), a.radius_m, fill=False, lw=2, ec=WALL_COLOR))
    else:
        ax.add_patch(
            Rectangle(
                (-a.width_m / 2, -a.height_m / 2),
                a.width_m,
                a.height_m,
                fill=False,
                lw=2,
                ec=WALL_COLOR,
            )
        )
    for ob in world.obstacles:
        if ob.is_circle:
            patch = Circle(ob.center_m, ob.radius_m, fc=OBSTACLE_COLOR, ec="0.3")
        else:
            patch = Polygon(ob.vertices_m, closed=True, fc=OBSTACLE_COLOR, ec="0.3")
        ax.add_patch(patch)
    if pose is not None:
        _draw_robot(world, ax, pose, ranges)
    xmin, xmax, ymin, ymax = a.bounds_m()
    pad = 0.05 * (xmax - xmin)
    ax.set_xlim(xmin - pad, xmax + pad)
    ax.set_ylim(ymin - pad, ymax + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")


def _draw_robot(world: World, ax, pose, ranges) -> None:
    b = world.body
    x, y, th = (float(v) for v in pose)
    ax.add_patch(Circle((x, y), b.radius_m, fc="white", ec=ROBOT_COLOR, lw=1.5, zorder=3))
    ax.plot(
        [x, x + b.radius_m * np.cos(th)],
        [y, y + b.radius_m * np.sin(th)],
        color=ROBOT_COLOR,
        lw=1.5,
        zorder=4,
    )
    if ranges is None:
        return
    ranges = np.asarray(ranges, dtype=np.float64)
    c, s = np.cos(th), np.sin(th)
    off = b.sensor_offsets_m
    ox = x + c * off[:, 0] - s * off[:, 1]
    oy = y + s * off[:, 0] + c * off[:, 1]
    ang = th + b.sensor_angles_rad.astype(np.float64)
    for i in range(b.n_sensors):
        hit = ranges[i] < b.max_range_m
        ax.plot(
            [ox[i], ox[i] + ranges[i] * np.cos(ang[i])],
            [oy[i], oy[i] + ranges[i] * np.sin(ang[i])],
            color=RAY_COLOR,
            lw=0.8,
            ls="-" if hit else ":",
            zorder=2,
        )


def trajectory_figure(world: World, t_s, poses, title: str | None = None) -> Figure:
    """A figure of the world with the path coloured by time and the final robot pose.

    Parameters
    ----------
    world : World
        Arena, obstacles and the robot drawn at the last pose.
    t_s : float[N]
        Sample times (s), for the colours.
    poses : float[N, 3]
        ``(x_m, y_m, heading_rad)`` at each time.
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
        Not attached to pyplot (no display needed).
    """
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    p = np.asarray(poses, dtype=np.float64)
    fig = Figure(figsize=(6, 5.2))
    ax = fig.add_subplot()
    draw_world(world, ax, pose=p[-1] if len(p) else None)
    if len(p) > 1:
        keep = path_points(p[:, :2], PATH_STEP_M)
        pts, tk = p[keep, :2].reshape(-1, 1, 2), t[keep]
        segs = np.concatenate([pts[:-1], pts[1:]], axis=1)
        lc = LineCollection(segs, cmap="viridis", lw=1.2, zorder=1)
        lc.set_array(0.5 * (tk[:-1] + tk[1:]))
        ax.add_collection(lc)
        fig.colorbar(lc, ax=ax, label="time (s)")
        # a pass-through robot may leave the arena: keep the whole path in view
        (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
        pad = 2 * world.body.radius_m
        ax.set_xlim(min(x0, p[:, 0].min() - pad), max(x1, p[:, 0].max() + pad))
        ax.set_ylim(min(y0, p[:, 1].min() - pad), max(y1, p[:, 1].max() + pad))
    if title:
        ax.set_title(title)
    return fig


def path_points(xy_m, step_m: float) -> np.ndarray:
    """Indices of the points of a path to draw it through, thinning a long path.

    The first point, then the first point of each further ``step_m`` of distance travelled,
    and the last (at least two points when N > 1).

    Parameters
    ----------
    xy_m : array_like, float[N, 2]
        The path's points (m), in order.
    step_m : float
        Distance travelled between kept points (m), > 0.

    Returns
    -------
    int ndarray
        Increasing indices into ``xy_m``.
    """
    xy = np.asarray(xy_m, dtype=np.float64)
    if len(xy) < 2:
        return np.arange(len(xy))
    travelled_m = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    stretch = np.floor(travelled_m / step_m)
    keep = np.flatnonzero(np.diff(stretch, prepend=-1.0) > 0)
    return keep if keep[-1] == len(xy) - 1 else np.append(keep, len(xy) - 1)


#: how the trajectory picture is saved (``Figure.savefig`` options)
TRAJECTORY_SAVE = {"dpi": 150, "bbox_inches": "tight"}


def save_trajectory(world: World, t_s, poses, path, title: str | None = None) -> Path:
    """Save the trajectory picture (`trajectory_figure`).

    Parameters
    ----------
    world, t_s, poses, title
        As for `trajectory_figure`.
    path : str or Path
        Ends in ``.png`` or ``.svg``; the format follows the suffix.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    if path.suffix.lower() not in (".png", ".svg"):
        raise ValueError(f"path must end in .png or .svg, got {path.name!r}")
    fig = trajectory_figure(world, t_s, poses, title=title)
    fig.savefig(path, **TRAJECTORY_SAVE)
    return path
