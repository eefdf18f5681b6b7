"""Serves a simulated arena on the bus: motor commands in, sensor readings out.

A thin shell around :class:`sim_robot.Arena`; all physics lives in the library.
Parameters (``[body.params]``): ``world`` (a world file, relative to the experiment file,
or a world table; default the paper's), any key of a world file overriding the world's
(``arena.radius_m``, ``obstacles``...), and ``seed`` (sensor noise; default the
experiment's seed).
"""

from __future__ import annotations

import numpy as np

import settings
from hub.config import ConfigError, EndpointSection, ExperimentConfig, check_value
from hub.endpoint import Endpoint
from hub.protocol import Description, MotorCommand, RunStart, SensorReading, StepWindow
from sim_robot import Arena, WorldError
from sim_robot.world import DEFAULT_WORLD_FILE, read_world_data, world_from_dict

DEFAULT_WORLD = str(DEFAULT_WORLD_FILE)


class ArenaEndpoint(Endpoint):
    """A simulated robot in a simulated arena, stepped by the run's period.

    Parameters
    ----------
    arena : Arena
        The world and robot; each run starts from its start pose.
    id : str
        Which body this is on the bus.
    """

    role, kind = "body", "sim_robot"

    def __init__(self, arena: Arena, id: str = "0"):
        super().__init__(id)
        self.arena = arena
        self.last_wheels_mps = (0.0, 0.0)

    @classmethod
    def check_config(cls, section: EndpointSection, cfg: ExperimentConfig) -> dict:
        """Check ``[body.params]`` (the world is built and validated, nothing else);
        return them resolved.

        ``world`` is a world file or a world table (as resolved params hold it); any other
        world key (``arena``, ``obstacles``, ...) overrides the world's.

        Parameters
        ----------
        section : EndpointSection
            The ``[body]`` section; its ``params`` are checked.
        cfg : ExperimentConfig
            The whole experiment: the default seed.

        Returns
        -------
        dict
            ``world`` (the world's contents: the file's with the overrides in place) and
            ``seed``: what the run uses, as the manifest records it.

        Raises
        ------
        ConfigError
            Naming ``body.params.<key>`` (``body.params.arena.radius_m must be ...``).
        """
        params = dict(section.params)
        world = params.pop("world", DEFAULT_WORLD)
        seed = check_value("body.params.seed", int, params.pop("seed", cfg.experiment.seed), ge=0)
        if isinstance(world, str):
            try:
                world = read_world_data(world)
            except ConfigError as exc:
                raise ConfigError(f"body.params.world: {exc}") from None
        elif not isinstance(world, dict):
            raise ConfigError(f"body.params.world must be a world file or table, got {world!r}")
        contents = settings.merge(world, params)
        try:
            world_from_dict(contents)
        except WorldError as exc:
            raise settings.under("body.params.", exc) from None
        return {"world": contents, "seed": seed}

    @classmethod
    def from_config(cls, section: EndpointSection, cfg: ExperimentConfig) -> ArenaEndpoint:
        params = cls.check_config(section, cfg)
        arena = Arena(world_from_dict(params["world"]), seed=params["seed"])
        return cls(arena, section.id)

    def describe(self) -> Description:
        body = self.arena.body
        return Description(
            role="body",
            id=self.id,
            kind=self.kind,
            sensor_angles_rad=body.sensor_angles_rad,
            max_range_m=float(body.max_range_m),
            wheel_base_m=float(body.wheel_base_m),
            radius_m=float(body.radius_m),
            max_wheel_mps=float(body.max_wheel_mps),
        )

    def warm_up(self) -> None:
        """Load the ray-casting kernels (reading the sensors changes nothing)."""
        self.arena.read_sensors()

    def start_run(self, run: RunStart) -> None:
        """The robot back at the world's start pose, stopped, at time 0."""
        self.arena.reset()
        self.last_wheels_mps = (0.0, 0.0)

    def make_safe(self) -> None:
        """Wheels stopped: steps the hub skips from now on see the robot standing."""
        self.last_wheels_mps = (0.0, 0.0)

    def step(self, m: MotorCommand, window: StepWindow) -> SensorReading:
        # Steps the hub skipped (realtime, lost input): the robot kept rolling.
        gap_s = window.t0_s - self.arena.t_s
        if gap_s > 1e-9:
            self.arena.step(*self.last_wheels_mps, gap_s)
        self.last_wheels_mps = (m.left_mps, m.right_mps)
        self.arena.step(m.left_mps, m.right_mps, window.period_s)
        return SensorReading(
            step=m.step,
            run=window.run,
            t_s=window.t1_s,
            ranges_m=self.arena.read_sensors(),
            pose=np.asarray(self.arena.pose, dtype=np.float64),
            contact=bool(self.arena.contact),
        )
