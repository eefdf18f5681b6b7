"""Live burst detection: the online detector fed a culture's spike stream, step by step.

The paper detects bursts and network bursts "on the fly". :class:`LiveBursts` buffers
each step's :class:`~hub.protocol.SpikeBatch` and feeds the detector once ``every_ms`` of
run time is buffered (its cost is mostly per call), mapping the culture's channel ids to
detector indices many steps at a time. It has no bus code: the burst observer
(:mod:`hub.burst_observer`) runs it in a process of its own, beside the loop.
"""

from __future__ import annotations

import numpy as np

from hub.analysis.bursts import BurstParams
from hub.analysis.network_bursts import NetworkBurstParams
from hub.analysis.online import NetworkBurst, OnlineBurstDetector
from hub.protocol import SpikeBatch


class LiveBursts:
    """Counts bursts and returns each network burst as it completes.

    Parameters
    ----------
    channel : int array
        The culture's channel ids (its ``Description.channel``).
    burst, network : BurstParams, NetworkBurstParams
    every_ms : float
        Run time buffered before the detector is fed.
    """

    def __init__(
        self,
        channel: np.ndarray,
        burst: BurstParams,
        network: NetworkBurstParams,
        every_ms: float,
    ):
        channel = np.asarray(channel, np.int64)
        self.detector = OnlineBurstDetector(channel.size, burst, network)
        self.index = np.zeros(int(channel.max(initial=0)) + 1, np.int64)
        self.index[channel] = np.arange(channel.size)
        self.every_ms = every_ms
        self.bursts = 0
        self.network_bursts = 0
        self._batches: list[SpikeBatch] = []  # added since the last feed
        self._until_ms = 0.0  # every spike before this has been buffered
        self._next_ms = every_ms

    def add(self, spikes: SpikeBatch) -> None:
        """Buffer one step's spikes (kept as they came: converted many steps at a time)."""
        self._batches.append(spikes)
        self._until_ms = spikes.t1_s * 1e3

    @property
    def until_ms(self) -> float:
        """Every spike before this run time (ms) has been added."""
        return self._until_ms

    @property
    def due(self) -> bool:
        """Whether enough run time is buffered to be worth a feed."""
        return bool(self._batches) and self._until_ms >= self._next_ms

    def work(self) -> list[NetworkBurst]:
        """Feed the buffer to the detector; return the network bursts completed."""
        batches, self._batches = self._batches, []
        done: list[NetworkBurst] = []
        if batches:
            t0_ms = np.repeat([b.t0_s * 1e3 for b in batches], [b.t_ms.size for b in batches])
            index = self.index[np.concatenate([b.channel for b in batches])]
            t_ms = t0_ms + np.concatenate([b.t_ms for b in batches])
            self.detector.add(index, t_ms)
            # A spike stamped at the window's very end may round a hair past it.
            until_ms = max(self._until_ms, t_ms[-1]) if t_ms.size else self._until_ms
            self._count(self.detector.advance(until_ms), done)
        self._next_ms = self._until_ms + self.every_ms
        return done

    def finish(self) -> list[NetworkBurst]:
        """End of the run: feed what is buffered and complete every burst still open (as
        offline detection does at the end of a record); return the network bursts
        completed."""
        done = self.work()
        self._count(self.detector.flush(), done)
        return done

    def under_way(self) -> float | None:
        """The start of a network burst under way (not complete yet), for displays; see
        :meth:`~hub.analysis.online.OnlineBurstDetector.under_way`."""
        return self.detector.under_way()

    def _count(self, events: list, done: list[NetworkBurst]) -> None:
        for event in events:
            if isinstance(event, NetworkBurst):
                self.network_bursts += 1
                done.append(event)
            else:
                self.bursts += 1
