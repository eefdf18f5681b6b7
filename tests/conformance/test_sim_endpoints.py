"""The conformance suite (hub/conformance.py) on the simulators: each keeps contract v2."""

from __future__ import annotations

import pytest

from hub import conformance
from hub.endpoint import RunRefused
from hub.protocol import SpikeBatch
from sim_network import LayoutConfig, Network, NetworkConfig
from sim_network.endpoint import NetworkEndpoint
from sim_robot import Arena
from sim_robot.endpoint import ArenaEndpoint
from tests.endpoints import EchoBody, EchoCulture

SMALL_CULTURE = NetworkConfig(layout=LayoutConfig(rows=4, cols=4))


def arena() -> ArenaEndpoint:
    return ArenaEndpoint(Arena.from_toml("configs/worlds/paper.toml", seed=1))


def network() -> NetworkEndpoint:
    return NetworkEndpoint(Network(SMALL_CULTURE, seed=1))


FACTORIES = {
    "ArenaEndpoint": arena,
    "NetworkEndpoint": network,
    "EchoBody": EchoBody,
    "EchoCulture": EchoCulture,
}


@pytest.mark.parametrize("check", conformance.CHECKS, ids=lambda c: c.__name__)
@pytest.mark.parametrize("name", sorted(FACTORIES))
def test_the_endpoint_keeps_the_contract(name, check):
    check(FACTORIES[name])


class RefusingBody(EchoBody):
    """A body that refuses every run."""

    def start_run(self, run):
        raise RunRefused("no motors today")


def test_the_suite_fails_an_endpoint_that_breaks_the_contract():
    with pytest.raises(AssertionError, match="no motors today"):
        conformance.check_run_lifecycle(RefusingBody)


class OwnPeriodCulture(EchoCulture):
    """A culture that times its spikes by its own file's 10 ms period, not the run's."""

    def step(self, s, window):
        out = super().step(s, window)
        k = window.step
        return SpikeBatch(run=out.run, step=k, t0_s=k * 0.01, t1_s=(k + 1) * 0.01,
                          channel=out.channel, t_ms=out.t_ms)  # fmt: skip


def test_the_suite_fails_an_endpoint_that_ignores_the_runs_period():
    with pytest.raises(AssertionError, match="spikes' t[01]_s"):
        conformance.check_replies_carry_run_and_window(OwnPeriodCulture)
