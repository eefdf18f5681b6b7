"""The one error type of sim_robot: a configuration error (settings.ConfigError)."""

from settings import ConfigError


class WorldError(ConfigError):
    """A world file or world description is invalid; the message names the key and why."""
