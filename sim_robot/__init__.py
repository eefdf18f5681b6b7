"""sim_robot: a 2-D arena with obstacles and a differential-drive robot with range finders.

A plain library (no bus): ``Arena.from_toml(path).step(left_mps, right_mps, dt_s)`` and
``read_sensors()``. Pictures in ``sim_robot.render``, trajectory metrics in
``sim_robot.metrics``.
"""

from .arena import Arena, ArenaStats
from .bodies import PRESETS, Body, custom_body, preset
from .errors import WorldError
from .ir import ir_value
from .kinematics import arc_step
from .metrics import trajectory_metrics
from .world import ArenaShape, Obstacle, World, load_world, world_from_dict

__all__ = [
    "PRESETS",
    "Arena",
    "ArenaShape",
    "ArenaStats",
    "Body",
    "Obstacle",
    "World",
    "WorldError",
    "arc_step",
    "custom_body",
    "ir_value",
    "load_world",
    "preset",
    "trajectory_metrics",
    "world_from_dict",
]
