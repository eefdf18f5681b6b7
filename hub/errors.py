"""The errors that end a run as a fault (the manifest's ``outcome = "fault"``, its
``reason`` the message)."""

from __future__ import annotations


class HubError(RuntimeError):
    """A run could not start or had to stop; the message says why."""


class EndpointDied(HubError):
    """An endpoint's liveliness token vanished during the steps (``policy.endpoint_death =
    "stop"``).

    Parameters
    ----------
    role, id : str
        The endpoint that died (also kept as attributes).
    step : int
        The step during which its token vanished.
    why : str
        How its death was seen.
    """

    def __init__(self, role: str, id: str, step: int, why: str = "its liveliness token vanished"):
        super().__init__(f"{role}/{id} died at step {step} ({why})")
        self.role, self.id, self.step = role, id, step
