"""An MEA stimulator/recorder that speaks the Lab Streaming Layer (pylsl).

**Spikes** come from an LSL stream found by name, type (default ``Spikes``) and, if given,
source id: irregular rate, **one sample per spike**, stamped with the spike's time on the
instrument's LSL clock; the sample's first channel names the electrode — a string (the
layout's channel name, e.g. ``a-010``) or an integer (the layout's channel id, 0..n-1).
A float stream is refused when it is opened.

**Stimulation** goes out on an LSL **marker outlet** this driver makes (type ``Markers``,
one string channel, irregular rate, source id ``neuvision-<name>``) for the lab's
stimulator program to read: one marker per pulse, JSON (:data:`MARKER_VERSION`)::

    {"v": 1, "kind": "pulse", "trigger": 7, "electrode": "a-010", "channel": 10,
     "amplitude_ua": 40.0, "phase_us": 150.0, "polarity": "negative_first",
     "shape": "biphasic"}

Pulses of one trigger share its number and the marker's LSL timestamp (when it was sent):
they are fired together, now. ``{"v": 1, "kind": "stop"}`` means: cancel whatever is
pending, deliver nothing more (sent when a run ends, is paused or the hub vanishes, and at
close). Only pulses the endpoint's safety gate admitted are ever sent. With no marker
outlet configured (``stim_outlet = ""``) the instrument is **record-only**
(:attr:`LslDriver.stimulates` is false): the endpoint refuses every pulse, counted.

**Clock**: LSL's own clock correction (``StreamInlet.time_correction()``, its round-trip
probes refreshed in the background) gives the instrument's clock against this machine's
LSL clock; each :meth:`LslDriver.sample_clock` turns it into a (``time.monotonic()``,
instrument time) pair, so offset and drift are fitted and reported as for the RHX driver.

LSL discovers streams by multicast: keep it on loopback for tests and demos with
``LSLAPICFG=adapters/mea/lsl_loopback.cfg`` (docs/mea.md).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable

import numpy as np
import pylsl

from adapters.mea.driver import ClockMap, spike_arrays
from adapters.mea.layout import ElectrodeLayout
from adapters.mea.safety import BiphasicPulse
from hub.endpoint import DeviceFault

log = logging.getLogger(__name__)

MARKER_VERSION = 1
MARKER_TYPE = "Markers"
INTEGER_FORMATS = (pylsl.cf_int8, pylsl.cf_int16, pylsl.cf_int32, pylsl.cf_int64)
PULL_WAIT_S = 0.1  # the spike reader's longest wait for a sample (how soon it sees a stop)


class LslError(DeviceFault):
    """The spike stream was not found, has the wrong shape, or was lost; no stimulator
    listens; LSL's clock correction did not come."""


def predicate(name: str, type_: str, source_id: str) -> str:
    """The XPath predicate that finds the spike stream (empty fields match anything).

    Parameters
    ----------
    name, type_, source_id : str
        The stream's name, type and source id; "" matches any.

    Raises
    ------
    ValueError
        A field holds a quote (``'``).
    """
    parts = [f"{k}='{v}'" for k, v in (("name", name), ("type", type_), ("source_id", source_id))
             if v]  # fmt: skip
    for value in (name, type_, source_id):
        if "'" in value:
            raise ValueError(f"an LSL stream field may not hold a quote: {value!r}")
    return " and ".join(parts)


def pulse_marker(pulse: BiphasicPulse, electrode: str, trigger: int) -> str:
    """One pulse as the marker outlet carries it (JSON, as in the module docstring).

    Parameters
    ----------
    pulse : BiphasicPulse
        An admitted pulse.
    electrode : str
        Its channel's name in the layout (``a-010``).
    trigger : int
        The number of the trigger it fires with (shared by the pulses fired together).
    """
    return json.dumps(
        {
            "v": MARKER_VERSION,
            "kind": "pulse",
            "trigger": trigger,
            "electrode": electrode,
            "channel": pulse.channel,
            "amplitude_ua": pulse.amplitude_ua,
            "phase_us": pulse.phase_us,
            "polarity": "negative_first" if pulse.negative_first else "positive_first",
            "shape": "biphasic",
        }
    )


STOP_MARKER = json.dumps({"v": MARKER_VERSION, "kind": "stop"})


class LslDriver:
    """Spikes from an LSL stream, stimulation on an LSL marker outlet; a
    :class:`~adapters.mea.driver.MeaDriver`.

    Parameters
    ----------
    layout : ElectrodeLayout
        Which channel name or id is which electrode.
    spike_stream, spike_type, spike_source_id : str
        The spike stream's name, type and source id ("" matches any; not all three empty).
    stim_outlet : str
        The marker outlet's name; "" for a record-only instrument.
    resolve_timeout_s : float
        How long :meth:`open` looks for the spike stream (and waits for LSL's first clock
        correction).
    stim_wait_s : float
        How long :meth:`start` waits for a stimulator to read the marker outlet.
    """

    def __init__(
        self,
        layout: ElectrodeLayout,
        spike_stream: str = "",
        spike_type: str = "Spikes",
        spike_source_id: str = "",
        stim_outlet: str = "",
        resolve_timeout_s: float = 5.0,
        stim_wait_s: float = 5.0,
    ):
        self.layout = layout
        self.query = predicate(spike_stream, spike_type, spike_source_id)
        if not self.query:
            raise ValueError("the spike stream needs a name, a type or a source id")
        self.stim_outlet = stim_outlet
        self.resolve_timeout_s, self.stim_wait_s = resolve_timeout_s, stim_wait_s
        self.counts: Counter[str] = Counter()
        self.clock = ClockMap([])
        self.fault: DeviceFault | None = None
        self.correction_s: float | None = None  # LSL's latest time_correction()
        self._names = layout.index()
        self._inlet: pylsl.StreamInlet | None = None
        self._outlet: pylsl.StreamOutlet | None = None
        self._by_name = True
        self._spikes: list[tuple[int, float, float]] = []  # channel, instrument s, arrival
        self._spikes_lock = threading.Lock()
        self.on_spikes: Callable[[], None] | None = None  # called after each read of spikes
        self._stop = threading.Event()
        self._reader: threading.Thread | None = None
        self._unheard_logged = False

    @property
    def stimulates(self) -> bool:
        """Whether a marker outlet is configured: False for a record-only instrument."""
        return bool(self.stim_outlet)

    # ------------------------------------------------------------ life

    def open(self) -> None:
        """Find the spike stream and check its shape, get LSL's first clock correction,
        make the marker outlet (if any), and start reading spikes."""
        found = pylsl.resolve_bypred(self.query, 1, self.resolve_timeout_s)
        if not found:
            raise LslError(
                f"no LSL spike stream matching {self.query} within {self.resolve_timeout_s:g} s"
            )
        if len(found) > 1:
            log.warning("%d LSL streams match %s: taking the first", len(found), self.query)
        info = found[0]
        fmt = info.channel_format()
        if fmt == pylsl.cf_string:
            self._by_name = True
        elif fmt in INTEGER_FORMATS:
            self._by_name = False
        else:
            raise LslError(
                f"the LSL spike stream {info.name()!r} carries format {fmt}: its first channel "
                "must name the electrode, as a string (the layout's name) or an integer (its id)"
            )
        # recover=False: a stream that goes away is a fault of the instrument, not a wait
        self._inlet = pylsl.StreamInlet(info, max_buflen=60, recover=False)
        try:
            self._inlet.open_stream(self.resolve_timeout_s)
            self.correction_s = self._inlet.time_correction(self.resolve_timeout_s)
        except (pylsl.util.TimeoutError, pylsl.util.LostError) as exc:
            raise LslError(f"the LSL spike stream {info.name()!r}: {exc}") from None
        if self.stim_outlet:
            marker = pylsl.StreamInfo(self.stim_outlet, MARKER_TYPE, 1, pylsl.IRREGULAR_RATE,
                                      pylsl.cf_string, f"neuvision-{self.stim_outlet}")  # fmt: skip
            self._outlet = pylsl.StreamOutlet(marker)
        self._reader = threading.Thread(target=self._read_spikes, name="lsl-spikes", daemon=True)
        self._reader.start()

    def start(self) -> None:
        """A run begins: the clock mapped afresh; a stimulator must be reading the markers."""
        if self.fault is not None:
            raise self.fault
        self.clock = ClockMap([])
        for _ in range(5):
            self.sample_clock()
        if self._outlet is not None and not self._outlet.wait_for_consumers(self.stim_wait_s):
            raise LslError(
                f"no stimulator reads the LSL marker outlet {self.stim_outlet!r} "
                f"(waited {self.stim_wait_s:g} s)"
            )

    def sample_clock(self) -> None:
        """One (local, instrument) pair: LSL's clock correction at this machine's LSL time."""
        if self.fault is not None:  # the reader found the stream lost
            raise self.fault
        try:
            correction = self._inlet.time_correction(self.resolve_timeout_s)
        except (pylsl.util.TimeoutError, pylsl.util.LostError) as exc:
            raise LslError(f"LSL clock correction: {exc}") from None
        t0 = time.monotonic()
        lsl_now = pylsl.local_clock()
        t1 = time.monotonic()
        self.correction_s = correction
        self.clock.pairs.append(((t0 + t1) / 2, lsl_now - correction))
        del self.clock.pairs[:-200]

    def stop(self) -> None:
        """Tell the stimulator to deliver nothing more (a ``stop`` marker)."""
        if self._outlet is not None:
            self._outlet.push_sample([STOP_MARKER])
            self.counts["stops"] += 1

    def finish(self) -> None:
        """The run is over: a ``stop`` marker (the stream has no run mode to leave)."""
        self.stop()

    def close(self) -> None:
        """Send a ``stop`` marker, stop reading spikes and close the stream and the outlet."""
        self._stop.set()
        self.stop()
        if self._reader is not None:
            self._reader.join(timeout=2.0)
        if self._inlet is not None:
            self._inlet.close_stream()
        self._inlet = self._outlet = None

    def beat(self) -> bool:
        """No stop guard here (a frozen adapter sends no markers): nothing to learn."""
        return False

    def rest(self) -> None:
        """No stop guard: nothing to tell."""

    def report(self) -> dict:
        """Counts, the fitted clock and LSL's latest correction (for ``describe``)."""
        out = {**dict(self.counts), **(self.clock.report() if self.clock.pairs else {})}
        if self.correction_s is not None:
            out["lsl_time_correction_s"] = self.correction_s
        out["stimulator"] = self.stim_outlet or "none (record-only)"
        return out

    # ------------------------------------------------------------ stimulation

    def deliver(self, pulses: list[BiphasicPulse]) -> None:
        """One marker per pulse, all with this trigger's number and timestamp."""
        if self._outlet is None:
            raise LslError("record-only: no LSL marker outlet to stimulate through")
        if not self._outlet.have_consumers():
            self.counts["pulses_unheard"] += len(pulses)
            if not self._unheard_logged:
                log.error("no stimulator reads the marker outlet %r: pulses sent unheard",
                          self.stim_outlet)  # fmt: skip
                self._unheard_logged = True
        trigger = self.counts["triggers"] + 1
        stamp = pylsl.local_clock()
        for i, p in enumerate(pulses):
            marker = pulse_marker(p, self.layout.names[p.channel], trigger)
            self._outlet.push_sample([marker], stamp, pushthrough=i == len(pulses) - 1)
        self.counts["triggers"] += 1
        self.counts["pulses"] += len(pulses)

    # ------------------------------------------------------------ spikes

    def _read_spikes(self) -> None:
        inlet = self._inlet
        while not self._stop.is_set():
            try:
                # the first sample as soon as it comes, then whatever else is there
                sample, stamp = inlet.pull_sample(PULL_WAIT_S)
                if sample is None:
                    continue
                samples, stamps = inlet.pull_chunk(0.0, 4096)
            except pylsl.util.LostError:
                if not self._stop.is_set():
                    self.fault = LslError("the LSL spike stream was lost")
                return
            now = time.monotonic()
            got = []
            for values, t in zip([sample, *samples], [stamp, *stamps], strict=True):
                channel = self._channel(values[0])
                if channel is None:
                    self.counts["unknown_channel"] += 1
                else:
                    got.append((channel, t, now))
            with self._spikes_lock:
                self._spikes.extend(got)
            if got and self.on_spikes is not None:
                self.on_spikes()

    def _channel(self, value) -> int | None:
        if self._by_name:
            return self._names.get(value)
        value = int(value)
        return value if 0 <= value < self.layout.n else None

    def take_spikes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every spike read since the last call: channel, instrument time (s), arrival."""
        with self._spikes_lock:
            spikes, self._spikes = self._spikes, []
        return spike_arrays(spikes)
