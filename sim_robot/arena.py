"""The simulator: a robot driving in a world, stepped by wheel speeds, read by range finders.

>>> arena = Arena.from_toml("configs/worlds/paper.toml", seed=0)
>>> arena.step(0.1, 0.12, 0.01)
>>> ranges_m = arena.read_sensors()
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .bodies import Body
from .geometry import cast_rays, disc_update
from .ir import ir_value
from .kinematics import arc_step, saturate, wrap_angle
from .physics import SolidResolver, build_space
from .world import World, load_world

#: largest centre displacement per collision substep, as a fraction of the robot radius
SOLID_SUBSTEP_FRACTION = 0.25


@dataclass
class ArenaStats:
    """Cumulative counters since the start (or the last ``reset``).

    Attributes
    ----------
    steps : int
    distance_m : float
        Path length of the robot's centre (sum of per-step chord lengths).
    obstacle_entries : int
        Times the robot's disc began to touch or overlap an obstacle (per obstacle; with solid
        obstacles these are collisions).
    arena_exits : int
        Times the robot's centre left the arena (only possible with pass-through walls).
    wall_contacts : int
        Times the robot's disc began to touch or cross the wall.
    time_in_obstacles_s : float
        Time spent with the disc touching or overlapping any obstacle (judged at step ends).
    time_outside_arena_s : float
        Time spent with the centre outside the arena (judged at step ends).
    """

    steps: int = 0
    distance_m: float = 0.0
    obstacle_entries: int = 0
    arena_exits: int = 0
    wall_contacts: int = 0
    time_in_obstacles_s: float = 0.0
    time_outside_arena_s: float = 0.0


class Arena:
    """A world with one robot in it.

    Parameters
    ----------
    world : World
        A validated world (``load_world`` or ``World(...)``).
    seed : int or None
        Seeds the range-finder noise generator (used only when ``world.noise_sd_m > 0``).
    """

    def __init__(self, world: World, seed: int | None = 0):
        self.world = world
        self.seed = seed
        g = world.geometry
        self._g = (g.obs_kind, g.obs_circle, g.poly_vertex, g.obs_start, g.wall_kind, g.wall_param)
        self._body = world.body
        self._angles = world.body.sensor_angles_rad.astype(np.float64)
        self._offsets = np.ascontiguousarray(world.body.sensor_offsets_m, dtype=np.float64)
        self._ranges = np.empty(world.body.n_sensors, dtype=np.float32)
        self._overlap = np.zeros(g.n_obstacles, dtype=np.bool_)
        self.space = build_space(world)
        solid = world.obstacles_solid or world.walls_solid
        self._resolver = SolidResolver(world, self.space) if solid else None
        self.reset()

    @classmethod
    def from_toml(cls, path: str | Path, seed: int | None = 0) -> Arena:
        """Load a world file and place the robot at its start pose.

        Parameters
        ----------
        path : str or Path
            A TOML world file (``docs/sim_robot.md``).
        seed : int or None
            Seeds the range-finder noise.

        Returns
        -------
        Arena
            At time 0.

        Raises
        ------
        WorldError
            The file is not a valid world (the message names the key).
        """
        return cls(load_world(path), seed=seed)

    # ------------------------------------------------------------ state

    def reset(self, pose: tuple[float, float, float] | None = None) -> None:
        """Back to time 0 with zeroed counters.

        The noise generator is re-seeded, so a reset run repeats its noise exactly.

        Parameters
        ----------
        pose : (x_m, y_m, heading_rad), optional
            Where the robot starts; default the world's start pose.
        """
        x, y, th = self.world.start_pose if pose is None else pose
        self._x, self._y, self._th = float(x), float(y), wrap_angle(float(th))
        self.t_s = 0.0
        self.stats = ArenaStats()
        self.wheel_mps = (0.0, 0.0)
        self._rng = np.random.default_rng(self.seed)
        self._overlap[:] = False
        self._update_flags()

    @property
    def body(self) -> Body:
        """The robot's body (the world's): size, wheels and sensors."""
        return self._body

    @property
    def pose(self) -> tuple[float, float, float]:
        """(x_m, y_m, heading_rad), heading in [-pi, pi]."""
        return (self._x, self._y, self._th)

    @property
    def contact(self) -> bool:
        """The robot's disc touches or overlaps an obstacle or the wall."""
        return self._any_overlap or self._touch

    @property
    def touching(self) -> np.ndarray:
        """bool[n_obstacles]: which obstacles the disc touches or overlaps now."""
        return self._overlap.copy()

    @property
    def outside(self) -> bool:
        """The robot's centre is outside the arena."""
        return self._outside

    def _update_flags(self) -> int:
        """Refresh the contact flags for the current pose; returns new obstacle entries."""
        entries, self._any_overlap, self._outside, self._touch = disc_update(
            self._x, self._y, self._body.radius_m, *self._g, self._overlap
        )
        return entries

    # ------------------------------------------------------------ stepping

    def step(self, left_mps: float, right_mps: float, dt_s: float) -> None:
        """Drive the wheels at constant speeds for ``dt_s`` seconds.

        Speeds saturate at ``±body.max_wheel_mps``. The pose follows the exact arc; with solid
        obstacles or walls the move is split into substeps of at most
        ``SOLID_SUBSTEP_FRACTION`` x radius, each followed by a push-out (the robot slides).
        ``stats`` counts the step (distance, entries, exits, contacts, times).

        Parameters
        ----------
        left_mps, right_mps : float
            Wheel speeds (m/s, finite).
        dt_s : float
            Duration (s, finite, > 0).
        """
        if not (dt_s > 0 and math.isfinite(dt_s)):
            raise ValueError(f"dt_s must be a finite number > 0, got {dt_s!r}")
        if not (math.isfinite(left_mps) and math.isfinite(right_mps)):
            raise ValueError(f"wheel speeds must be finite, got ({left_mps!r}, {right_mps!r})")
        b = self._body
        left = saturate(float(left_mps), b.max_wheel_mps)
        right = saturate(float(right_mps), b.max_wheel_mps)
        self.wheel_mps = (left, right)
        x0, y0 = self._x, self._y
        if self._resolver is None:
            self._x, self._y, self._th = arc_step(
                x0, y0, self._th, left, right, b.wheel_base_m, dt_s
            )
            travelled = math.hypot(self._x - x0, self._y - y0)
        else:
            reach = max(abs(left), abs(right)) * dt_s
            n_sub = max(1, math.ceil(reach / (SOLID_SUBSTEP_FRACTION * b.radius_m)))
            sub_dt = dt_s / n_sub
            travelled = 0.0
            for _ in range(n_sub):
                xa, ya = self._x, self._y
                x, y, self._th = arc_step(xa, ya, self._th, left, right, b.wheel_base_m, sub_dt)
                self._x, self._y = self._resolver.resolve(x, y, xa, ya)
                travelled += math.hypot(self._x - xa, self._y - ya)
        self.t_s += dt_s
        was_out, was_touch = self._outside, self._touch
        entries = self._update_flags()
        s = self.stats
        s.steps += 1
        s.distance_m += travelled
        s.obstacle_entries += entries
        if self._outside and not was_out:
            s.arena_exits += 1
        if self._touch and not was_touch:
            s.wall_contacts += 1
        if self._any_overlap:
            s.time_in_obstacles_s += dt_s
        if self._outside:
            s.time_outside_arena_s += dt_s

    # ------------------------------------------------------------ sensing

    def read_sensors(self) -> np.ndarray:
        """What the range finders see from the current pose.

        Gaussian noise of ``world.noise_sd_m`` (seeded) is added and clipped when the world
        asks for it.

        Returns
        -------
        float32[n_sensors]
            Range (m) of each range finder, in the body's sensor order, in
            ``[0, max_range_m]``; exactly ``max_range_m`` when nothing is within range.
        """
        cast_rays(
            self._x,
            self._y,
            self._th,
            self._offsets,
            self._angles,
            self._body.max_range_m,
            *self._g,
            self._ranges,
        )
        out = self._ranges.copy()
        sd = self.world.noise_sd_m
        if sd > 0.0:
            noisy = out + self._rng.normal(0.0, sd, out.shape)
            out = np.clip(noisy, 0.0, self._body.max_range_m).astype(np.float32)
        return out

    def read_ir(self) -> np.ndarray:
        """The range finders as Khepera-like IR values.

        Uses ``body.ir_model``, or the Khepera II response when the body names none.

        Returns
        -------
        float32[n_sensors]
            IR proximity values, 0–1023, higher = nearer (`ir_value` of `read_sensors`).
        """
        ranges = self.read_sensors().astype(np.float64)
        # "nothing hit" is max_range_m exactly, not its float32 rounding
        ranges[ranges == np.float32(self._body.max_range_m)] = self._body.max_range_m
        return ir_value(ranges, self._body.ir_model or "khepera2")
