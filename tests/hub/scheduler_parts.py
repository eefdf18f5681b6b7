"""What a scheduler's tests give it in place of the hub's input policy and the endpoints'
replies: inputs that say which reply each was coded from."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Input:
    """An input as the test's policy makes it: coded from the reply of step ``source``
    (None: the reply was missing, or step 0)."""

    role: str
    step: int
    source: int | None

    def encode(self) -> bytes:
        return b""


class Inputs:
    """The policy's two questions (hub.policy.InputPolicy), answered with :class:`Input`."""

    def motor_for(self, k, spikes):
        return Input("body", k, None if spikes is None else spikes.step)

    def stim_for(self, k, sensors):
        return Input("culture", k, None if sensors is None else sensors.step)


@dataclass(frozen=True)
class Reply:
    step: int
