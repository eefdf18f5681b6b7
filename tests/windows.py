"""A run and its step windows for tests that build messages by hand (contract v2)."""

from __future__ import annotations

from hub.protocol import StepWindow

RUN = "0" * 32  # a well-formed run id
PERIOD_S = 0.01


def W(step: int, period_s: float = PERIOD_S) -> StepWindow:
    """The window of ``step`` in the test run."""
    return StepWindow.of(RUN, step, period_s)
