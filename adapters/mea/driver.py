"""What the MEA endpoint needs of an instrument driver, and the clock map drivers share.

:class:`MeaDriver` is the small interface :class:`~adapters.mea.endpoint.MeaEndpoint` calls;
two drivers implement it: :class:`~adapters.mea.rhx.RhxDriver` (Intan RHX over TCP) and
:class:`~adapters.mea.lsl.LslDriver` (Lab Streaming Layer). A driver's clock is a
:class:`ClockMap` of the instrument's time against ``time.monotonic()``.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from adapters.mea.layout import ElectrodeLayout
from adapters.mea.safety import BiphasicPulse
from hub.endpoint import DeviceFault


def spike_arrays(spikes: list[tuple], seconds_per_tick: float = 1.0):
    """Spikes read as tuples, as the three arrays of :meth:`MeaDriver.take_spikes`.

    Parameters
    ----------
    spikes : list of (channel, instrument time, arrival)
        Arrival on ``time.monotonic()``'s clock (s).
    seconds_per_tick : float
        The instrument time's unit, in s.

    Returns
    -------
    channel : uint32[n]
    inst_s : float64[n]
        Instrument time, s.
    arrived : float64[n]
        Arrival, s on ``time.monotonic()``'s clock.
    """
    if not spikes:
        return np.zeros(0, np.uint32), np.zeros(0), np.zeros(0)
    arr = np.array(spikes, dtype=np.float64)
    return arr[:, 0].astype(np.uint32), arr[:, 1] * seconds_per_tick, arr[:, 2]


@dataclass
class ClockMap:
    """The instrument's clock against ``time.monotonic()``: ``inst_s = a + b · local_s``,
    fitted to (local, instrument) pairs; the offset and the drift are reported."""

    pairs: list[tuple[float, float]]
    _fitted: tuple = field(default=(None, (0.0, 1.0)), init=False, repr=False, compare=False)

    def fit(self) -> tuple[float, float]:
        """``(a, b)``, refitted only when a pair came: a window's answer maps its spikes with
        it, and a fit costs ~0.1 ms of the interpreter that a pulse may be waiting for."""
        snapshot = self.pairs[:]  # pairs are added from another thread
        seen = (len(snapshot), snapshot[-1] if snapshot else None)
        if self._fitted[0] == seen:
            return self._fitted[1]
        pairs = np.array(snapshot, dtype=np.float64).reshape(-1, 2)
        local, inst = pairs[:, 0], pairs[:, 1]
        if local.size < 2 or np.ptp(local) < 0.5:
            fitted = float(np.median(inst - local)), 1.0
        else:
            b, a = np.polyfit(local, inst, 1)
            fitted = float(a), float(b)
        self._fitted = (seen, fitted)
        return fitted

    def to_local(self, inst_s: np.ndarray) -> np.ndarray:
        """Instrument times (s) as times on ``time.monotonic()``'s clock (s), by the fit."""
        a, b = self.fit()
        return (np.asarray(inst_s) - a) / b

    def report(self) -> dict:
        """``clock_offset_s`` is ``a`` (instrument time at local time 0);
        ``clock_offset_latest_s`` the offset at the latest pair, drift included."""
        a, b = self.fit()
        return {
            "clock_offset_s": a,
            "clock_offset_latest_s": a + (b - 1.0) * self.pairs[-1][0],
            "clock_drift_ppm": (b - 1.0) * 1e6,
            "clock_pairs": len(self.pairs),
        }


class MeaDriver(Protocol):
    """An MEA stimulator/recorder as the endpoint drives it (thread-safe where noted).

    Attributes
    ----------
    layout : ElectrodeLayout
        Channel id on the wire → instrument name and position.
    counts : Counter
        The driver's own counts (triggers, pulses, malformed input…), in ``describe``.
    clock : ClockMap
        Instrument time against ``time.monotonic()``; pairs added by :meth:`sample_clock`.
    fault : DeviceFault or None
        Set (by the driver's reader, or by the endpoint) when the instrument failed.
    stimulates : bool
        False for a record-only instrument: the endpoint then refuses every pulse.
    on_spikes : callable or None
        Called (from the driver's reader) each time spikes were read: the endpoint
        streams them (:meth:`take_spikes`).
    """

    layout: ElectrodeLayout
    counts: Counter
    clock: ClockMap
    fault: DeviceFault | None
    stimulates: bool
    on_spikes: Callable[[], None] | None

    def open(self) -> None:
        """Connect, make nothing deliverable, start reading spikes."""

    def start(self) -> None:
        """A run begins: the instrument running, the clock mapped afresh."""

    def sample_clock(self) -> None:
        """Add one (local, instrument) pair to :attr:`clock`."""

    def deliver(self, pulses: list[BiphasicPulse]) -> None:
        """Fire these (already admitted) pulses together, now."""

    def take_spikes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every spike read since the last call: channel (uint32), instrument time (s),
        local arrival (``time.monotonic()``) (thread-safe)."""

    def stop(self) -> None:
        """Nothing more delivered; the recording goes on (a pause, an input timeout: the
        run may go on, and its spikes with it)."""

    def finish(self) -> None:
        """The run is over: nothing more delivered, and the instrument out of its run."""

    def close(self) -> None:
        """Stop, and let go of the instrument."""

    def beat(self) -> bool:
        """This process lives (called by the endpoint's device worker at least every
        0.1 s): True when a stop guard made the instrument safe since the last beat, the
        process having been frozen. A driver with no guard returns False."""

    def rest(self) -> None:
        """The beats stop on purpose (the device worker ends)."""

    def report(self) -> dict:
        """Counts and the fitted clock (``clock_offset_s``, ``clock_drift_ppm``…) for
        ``describe``."""
