"""Settings: the one loader of every configuration file of the project.

Experiment files (``hub.config``), culture files (``sim_network.config``) and world files
(``sim_robot.world``) are all read here: TOML only, with a clear error for anything else;
``extends`` with one merge rule; paths relative to the file that names them; ``key=value``
overrides typed as TOML; validation against dataclasses by dotted key; one
:class:`ConfigError`. A neutral package: it imports nothing of the project, and the
simulators and the hub both import it.
"""

from settings.errors import ConfigError, under
from settings.files import apply_overrides, load, merge, read_toml, resolve_paths
from settings.overrides import get_dotted, parse_override, parse_value, set_dotted
from settings.schema import (
    bounds,
    build,
    check_known,
    coerce,
    known_keys,
    to_plain,
    with_overrides,
)

__all__ = [
    "ConfigError",
    "apply_overrides",
    "bounds",
    "build",
    "check_known",
    "coerce",
    "get_dotted",
    "known_keys",
    "load",
    "merge",
    "parse_override",
    "parse_value",
    "read_toml",
    "resolve_paths",
    "set_dotted",
    "to_plain",
    "under",
    "with_overrides",
]
