"""Behaviour metrics of a recorded trajectory (poses over time) in a world.

The definitions match the live counters of ``Arena.stats`` (same geometry kernel), so a
trajectory recorded at every step of a pass-through world gives the same numbers.
"""

from __future__ import annotations

import numpy as np

from .world import World, disc_flags

#: side of the grid cells used for arena coverage (m)
COVERAGE_CELL_M = 0.05


def trajectory_metrics(
    world: World,
    t_s: np.ndarray,
    poses: np.ndarray,
    cell_m: float = COVERAGE_CELL_M,
    radius_m: float | None = None,
) -> dict:
    """Summarise a trajectory.

    Parameters
    ----------
    world : World
        The world it was recorded in (arena, obstacles, robot radius).
    t_s : float[N]
        Sample times, non-decreasing.
    poses : float[N, 3]
        ``(x_m, y_m, heading_rad)`` at each time.
    cell_m : float
        Coverage grid cell side (default ``COVERAGE_CELL_M`` = 0.05 m).
    radius_m : float, optional
        The robot's disc (default the world's robot): a recorded body may be another robot
        than the one the world file describes.

    Returns
    -------
    dict
        ``duration_s``; ``distance_m`` (sum of straight segments between samples);
        ``mean_speed_mps`` (distance / duration); ``obstacle_entries`` (per obstacle, the
        samples where the robot's disc begins to touch or overlap it); ``arena_exits`` (the
        centre goes from inside to outside the arena); ``wall_contacts`` (the disc begins to
        touch or cross the wall); ``time_in_obstacles_s`` and ``time_outside_arena_s`` (each
        interval ``t[i-1]..t[i]`` counted by the state at ``t[i]``); ``coverage_fraction``
        (visited cells / arena cells, over a grid of ``cell_m`` squares aligned on the arena's
        bounding box whose centres lie inside the arena; a cell is visited when a sample
        centre falls in it), with ``coverage_cells_visited``, ``coverage_cells_total`` and
        ``coverage_cell_m``. Transitions are counted from the first sample on, so a recording
        that starts inside an obstacle does not count that as an entry.
    """
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"poses must have shape (N, 3), got {p.shape}")
    if t.shape[0] != p.shape[0] or t.shape[0] == 0:
        raise ValueError(f"t_s and poses must have the same length >= 1, got {t.size}, {len(p)}")
    if np.any(np.diff(t) < 0) or not np.all(np.isfinite(t)) or not np.all(np.isfinite(p)):
        raise ValueError("t_s must be finite and non-decreasing, poses finite")
    if radius_m is not None and not radius_m > 0:
        raise ValueError(f"radius_m must be > 0, got {radius_m!r}")
    if not cell_m > 0:
        raise ValueError(f"cell_m must be > 0, got {cell_m!r}")
    x = np.ascontiguousarray(p[:, 0])
    y = np.ascontiguousarray(p[:, 1])
    overlap, outside, touch = disc_flags(world, x, y, radius_m)
    dt = np.diff(t)
    duration = float(t[-1] - t[0])
    distance = float(np.hypot(np.diff(x), np.diff(y)).sum())
    visited, total = _coverage(world, x[~outside], y[~outside], cell_m)
    return {
        "duration_s": duration,
        "distance_m": distance,
        "mean_speed_mps": distance / duration if duration > 0 else 0.0,
        "obstacle_entries": int(np.count_nonzero(overlap[1:] & ~overlap[:-1])),
        "arena_exits": int(np.count_nonzero(outside[1:] & ~outside[:-1])),
        "wall_contacts": int(np.count_nonzero(touch[1:] & ~touch[:-1])),
        "time_in_obstacles_s": float(dt[overlap[1:].any(axis=1)].sum()),
        "time_outside_arena_s": float(dt[outside[1:]].sum()),
        "coverage_fraction": visited / total if total else 0.0,
        "coverage_cells_visited": visited,
        "coverage_cells_total": total,
        "coverage_cell_m": float(cell_m),
    }


def _coverage(world: World, x: np.ndarray, y: np.ndarray, cell_m: float) -> tuple[int, int]:
    xmin, xmax, ymin, ymax = world.arena.bounds_m()
    nx = int(np.ceil((xmax - xmin) / cell_m))
    ny = int(np.ceil((ymax - ymin) / cell_m))
    cx = xmin + (np.arange(nx) + 0.5) * cell_m
    cy = ymin + (np.arange(ny) + 0.5) * cell_m
    gx, gy = np.meshgrid(cx, cy, indexing="ij")
    a = world.arena
    if a.shape == "circle":
        in_arena = gx**2 + gy**2 <= a.radius_m**2
    else:
        in_arena = (np.abs(gx) <= a.width_m / 2) & (np.abs(gy) <= a.height_m / 2)
    ix = np.clip(((x - xmin) / cell_m).astype(np.int64), 0, nx - 1)
    iy = np.clip(((y - ymin) / cell_m).astype(np.int64), 0, ny - 1)
    hit = np.zeros((nx, ny), dtype=np.bool_)
    hit[ix, iy] = True
    return int(np.count_nonzero(hit & in_arena)), int(np.count_nonzero(in_arena))
