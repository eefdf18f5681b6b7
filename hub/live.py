"""Live burst detection: the hub's use of the online detector on the spike stream.

The paper detects bursts and network bursts "on the fly". :class:`LiveBursts`
takes each step's :class:`~hub.protocol.SpikeBatch`, maps the culture's channel
ids to detector indices, and feeds the detector in batches of ``every_ms`` of
simulated time (fewer calls in lockstep; 0 feeds every step, for realtime).
"""

from __future__ import annotations

import numpy as np

from hub.analysis.bursts import BurstParams
from hub.analysis.network_bursts import NetworkBurstParams
from hub.analysis.online import NetworkBurst, OnlineBurstDetector
from hub.protocol import Description, SpikeBatch


class LiveBursts:
    """Counts bursts and returns each network burst as it completes."""

    def __init__(
        self,
        culture: Description,
        burst: BurstParams,
        network: NetworkBurstParams,
        every_ms: float,
    ):
        self.detector = OnlineBurstDetector(culture.channel.size, burst, network)
        self.index = np.zeros(int(culture.channel.max(initial=0)) + 1, np.int64)
        self.index[culture.channel] = np.arange(culture.channel.size)
        self.every_ms = every_ms
        self.bursts = 0
        self.network_bursts = 0
        self._buffer: list[tuple[np.ndarray, np.ndarray]] = []
        self._until_ms = 0.0
        self._next_ms = every_ms

    def add(self, spikes: SpikeBatch) -> list[NetworkBurst]:
        """Take one step's spikes; returns the network bursts completed by them (if fed)."""
        t_ms = spikes.t0_s * 1e3 + spikes.t_ms.astype(np.float64)
        self._buffer.append((self.index[spikes.channel], t_ms))
        self._until_ms = spikes.t1_s * 1e3
        return self.flush() if self._until_ms >= self._next_ms else []

    def flush(self) -> list[NetworkBurst]:
        """Feed what is buffered; returns the network bursts completed."""
        if not self._buffer:
            return []
        index = np.concatenate([b[0] for b in self._buffer])
        t_ms = np.concatenate([b[1] for b in self._buffer])
        self._buffer.clear()
        self._next_ms = self._until_ms + self.every_ms
        # A spike stamped at the window's very end may round a hair past it.
        until_ms = max(self._until_ms, t_ms[-1]) if t_ms.size else self._until_ms
        done = []
        for event in self.detector.feed(index, t_ms, until_ms=until_ms):
            if isinstance(event, NetworkBurst):
                self.network_bursts += 1
                done.append(event)
            else:
                self.bursts += 1
        return done
