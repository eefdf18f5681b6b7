"""The one error type of sim_robot."""


class WorldError(ValueError):
    """A world file or world description is invalid; the message names the key and why."""
