"""The one error type of every configuration in the project."""

from __future__ import annotations


class ConfigError(ValueError):
    """A configuration file or value that is missing, unreadable, unknown or invalid.

    The message starts with what is wrong: the dotted key (``loop.period_ms must be > 0,
    got -5.0``) or the file (``config file x.png is not a text file``).
    """


def under(prefix: str, exc: ConfigError) -> ConfigError:
    """The same error (same class) with its dotted key placed under ``prefix``.

    ``under("culture.params.", ConfigError("noise.sd must be >= 0, got -1.0"))`` reads
    ``culture.params.noise.sd must be >= 0, got -1.0``.

    Parameters
    ----------
    prefix : str
        Dotted path of the table the error's key is in, with its trailing dot.
    exc : ConfigError
        The error raised for a key of that table; left unchanged.
    """
    return type(exc)(f"{prefix}{exc}")
