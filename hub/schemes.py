"""The coding/decoding interface: how sensors become stimulation and spikes motion.

A scheme is named in the experiment file as ``module:function``. The function
is a *factory*: called once, before step 0, with a :class:`SchemeContext`, it
returns the per-step callable::

    coder   = factory(ctx)   ;  coder(sensors: SensorReading, window: StepWindow) -> Stimulation
    decoder = factory(ctx)   ;  decoder(spikes: SpikeBatch, window: StepWindow)   -> MotorCommand

``window`` is the step the output is for (its ``step``, ``run`` and run time
``[t0_s, t1_s)``); the output carries it (``Stimulation(**window.stamp, ...)``,
``Stimulation.none(window)``, ``MotorCommand.stop(window)``).

The factory validates ``ctx.params`` (raising :class:`~hub.config.ConfigError`
naming ``coding.params.<key>``) and may keep state in the callable it returns.
The checks that need no description (unknown names, values out of their limits) go in a
function of the context that the factory calls first and names with :func:`checked_by`:
:func:`check_scheme` runs it before the run, with no descriptions (``ctx.body`` and
``ctx.culture`` None), so a bad parameter is a config error before anything starts; what
needs the endpoints (more sites than channels) is checked when the factory is called,
once they have described themselves. The factory may also keep state in the callable
(a decoder's averaging window, say). Coders and decoders are plain functions of
messages: they can be tested with no bus. The hub calls the coder with the
body's reading of step k−1 to stimulate at step k, and the decoder with the
culture's spikes of step k−1 to drive at step k.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field

from hub.config import ConfigError, check_value
from hub.protocol import (
    Description,
    MotorCommand,
    SensorReading,
    SpikeBatch,
    StepWindow,
    Stimulation,
)

Coder = Callable[[SensorReading, StepWindow], Stimulation]
Decoder = Callable[[SpikeBatch, StepWindow], MotorCommand]


@dataclass(frozen=True)
class SchemeContext:
    """What a scheme may know: both endpoints' descriptions and its parameters."""

    body: Description | None  # None: checking the params before the endpoints describe
    culture: Description | None
    params: dict = field(default_factory=dict)
    period_ms: float = 10.0
    seed: int = 0
    section: str = "coding"  # for error messages: "<section>.params.<key>"

    def param(self, name: str, default, *, kind=float, ge=None, gt=None, le=None, bounds=""):
        """A validated parameter: ``params[name]`` or ``default``.

        Parameters
        ----------
        name : str
            The parameter's name in ``params``.
        default
            Its value when absent; None: None is returned (a default that needs a
            description).
        kind : type
            What the value must be.
        ge, gt, le : float, optional
            Its limits.
        bounds : str
            Where limits that follow other parameters come from, added to the error.

        Raises
        ------
        ConfigError
            Naming ``<section>.params.<name>``.
        """
        if default is None and name not in self.params:
            return None
        value = self.params.get(name, default)
        dotted = f"{self.section}.params.{name}"
        try:
            return check_value(dotted, kind, value, gt=gt, ge=ge, le=le)
        except ConfigError as exc:
            if not bounds:
                raise
            raise ConfigError(f"{exc} ({bounds})") from None

    def check_params(self, known: set[str]) -> None:
        """Reject parameters the scheme does not know, by dotted name."""
        for name in self.params:
            if name not in known:
                raise ConfigError(
                    f"{self.section}.params.{name} is not a parameter of this scheme; "
                    f"known: {', '.join(sorted(known)) or 'none'}"
                )


def load_scheme(spec: str, section: str) -> Callable[[SchemeContext], Callable]:
    """Import the factory named ``module:function``.

    Parameters
    ----------
    spec : str
        ``module:function``.
    section : str
        ``"coding"`` or ``"decoding"``, named by the error.

    Raises
    ------
    ConfigError
        The module does not import, or has no such callable; naming ``<section>.scheme``.
    """
    module_name, _, attr = spec.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(f"{section}.scheme: cannot import {module_name!r}: {exc}") from None
    factory = getattr(module, attr, None)
    if not callable(factory):
        raise ConfigError(f"{section}.scheme: {module_name} has no callable {attr!r}")
    return factory


def checked_by(check: Callable[[SchemeContext], object]) -> Callable:
    """Name ``check(ctx)`` the factory's checks that need no description (the factory
    calls it too: one place for each check)."""

    def mark(factory):
        factory.check = check
        return factory

    return mark


def check_scheme(section: str, spec: str, params: dict, period_ms: float, seed: int = 0) -> None:
    """Check a scheme before the run: it imports, and its params pass the factory's
    description-free checks (:func:`checked_by`; a factory without them: only when called).

    Parameters
    ----------
    section : str
        ``"coding"`` or ``"decoding"``.
    spec : str
        The scheme, ``module:function``.
    params : dict
        Its parameters (``<section>.params``).
    period_ms : float
        The loop's period.
    seed : int
        The experiment's seed.

    Raises
    ------
    ConfigError
        Naming ``<section>.scheme`` or ``<section>.params.<key>``.
    """
    factory = load_scheme(spec, section)
    check = getattr(factory, "check", None)
    if check is not None:
        ctx = SchemeContext(None, None, dict(params), period_ms, seed, section)
        check(ctx)


def _no_params(ctx: SchemeContext) -> None:
    ctx.check_params(set())


@checked_by(_no_params)
def no_stimulation(ctx: SchemeContext) -> Coder:
    """Never stimulate: the blind control of the paper (spontaneous activity only)."""
    _no_params(ctx)
    return lambda sensors, window: Stimulation.none(window)


@checked_by(_no_params)
def stopped(ctx: SchemeContext) -> Decoder:
    """Always stand still, whatever the culture does."""
    _no_params(ctx)
    return lambda spikes, window: MotorCommand.stop(window)
