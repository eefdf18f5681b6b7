"""Plain records crossing the library boundary: pulses in, spikes out, the channel layout."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim_network import pulse_kernels


class PulseError(ValueError):
    """A stimulation pulse is malformed (lengths differ, negative width, unknown channel...)."""


_FIELDS = ("channel", "amplitude_ua", "width_ms", "onset_ms")
_DTYPES = (np.dtype(np.uint32), np.dtype(np.float32), np.dtype(np.float32), np.dtype(np.float32))


@dataclass(frozen=True)
class Pulses:
    """Monophasic current pulses in channel space, as parallel arrays of equal length.

    Attributes
    ----------
    channel : uint32[k]
        Channel of each pulse (a neuron, or an electrode of the virtual MEA).
    amplitude_ua : float32[k]
        Amplitude (µA; the model current per µA is ``stimulation.model_current_per_ua``).
    width_ms : float32[k]
        Duration, >= 0.
    onset_ms : float32[k]
        Start, >= 0, relative to the start of the `Network.run` call that receives them.

    Values are converted to these dtypes on construction; malformed ones raise `PulseError`.
    """

    channel: np.ndarray  # uint32[k]
    amplitude_ua: np.ndarray  # float32[k]
    width_ms: np.ndarray  # float32[k]
    onset_ms: np.ndarray  # float32[k]

    def __post_init__(self) -> None:
        if not self._valid_as_given():
            self._normalise()

    def _valid_as_given(self) -> bool:
        """Quick path: True if the fields already have their dtypes and valid values (as a
        hub's Stimulation gives them), so nothing needs converting; False sends them to
        :meth:`_normalise`, which converts what it can and names what is wrong."""
        arrays = (self.channel, self.amplitude_ua, self.width_ms, self.onset_ms)
        for arr, dtype in zip(arrays, _DTYPES, strict=True):
            if type(arr) is not np.ndarray or arr.dtype != dtype or arr.ndim != 1:
                return False
        n = self.channel.size
        if any(arr.size != n for arr in arrays):
            return False
        return n == 0 or pulse_kernels.values_ok(self.amplitude_ua, self.width_ms, self.onset_ms)

    def _normalise(self) -> None:
        arrays = {}
        for name, dtype in zip(_FIELDS, _DTYPES, strict=True):
            raw = np.asarray(getattr(self, name))
            if raw.ndim != 1:
                raw = raw.reshape(-1)
            if name == "channel" and raw.size:
                whole = raw.dtype.kind in "iu" or np.all(np.mod(raw, 1) == 0)
                if not whole or np.any(raw < 0):
                    raise PulseError(f"pulses.channel must be non-negative integers, got {raw!r}")
            arrays[name] = raw.astype(dtype)
            object.__setattr__(self, name, arrays[name])
        n = arrays["channel"].size
        for name, arr in arrays.items():
            if arr.size != n:
                raise PulseError(f"pulses.{name} has length {arr.size}, expected {n}")
        for name in ("amplitude_ua", "width_ms", "onset_ms"):
            if not np.all(np.isfinite(arrays[name])):
                raise PulseError(f"pulses.{name} must be finite")
        if np.any(arrays["width_ms"] < 0):
            raise PulseError("pulses.width_ms must be >= 0")
        if np.any(arrays["onset_ms"] < 0):
            raise PulseError("pulses.onset_ms must be >= 0")

    def __len__(self) -> int:
        return int(self.channel.size)

    @classmethod
    def empty(cls) -> Pulses:
        """No pulses.

        Returns
        -------
        Pulses
            Of length 0.
        """
        return cls(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))

    @classmethod
    def single(
        cls, channels, amplitude_ua: float, width_ms: float, onset_ms: float = 0.0
    ) -> Pulses:
        """The same pulse into each of some channels at one onset.

        Parameters
        ----------
        channels : int or array_like of int
            The channels.
        amplitude_ua, width_ms, onset_ms : float
            The pulse (onset relative to the start of the receiving `run` call).

        Returns
        -------
        Pulses
            One pulse per channel.
        """
        ch = np.atleast_1d(np.asarray(channels))
        k = ch.size
        return cls(ch, np.full(k, amplitude_ua), np.full(k, width_ms), np.full(k, onset_ms))


@dataclass(frozen=True)
class Spikes:
    """Spikes sorted by time.

    Attributes
    ----------
    channel : uint32[k]
        Channel (neuron index, or electrode) of each spike.
    t_ms : float64[k]
        Absolute simulated time of each spike (ms); a spike found in step k is at (k + 1)·dt.
    """

    channel: np.ndarray
    t_ms: np.ndarray

    def __len__(self) -> int:
        return int(self.channel.size)

    @classmethod
    def concat(cls, parts: list[Spikes]) -> Spikes:
        """Join the spike records of consecutive runs.

        Parameters
        ----------
        parts : list of Spikes
            In time order.

        Returns
        -------
        Spikes
            All of them, one after the other (empty for no parts).
        """
        if not parts:
            return cls(np.zeros(0, np.uint32), np.zeros(0, np.float64))
        return cls(
            np.concatenate([p.channel for p in parts]), np.concatenate([p.t_ms for p in parts])
        )


@dataclass(frozen=True)
class Channels:
    """The channels a network records and stimulates through.

    Attributes
    ----------
    channel : uint32[n]
        Channel ids, 0..n-1.
    x_um, y_um : float32[n]
        Positions (µm).
    cell_type : uint8[n] or None
        0 excitatory, 1 inhibitory, when the channels are neurons; None for electrodes.
    kind : str
        ``"neuron"`` or ``"electrode"``.
    """

    channel: np.ndarray  # uint32[n]
    x_um: np.ndarray  # float32[n]
    y_um: np.ndarray  # float32[n]
    cell_type: np.ndarray | None  # uint8[n] (0 exc, 1 inh) when kind == "neuron"
    kind: str  # "neuron" | "electrode"

    def __len__(self) -> int:
        return int(self.channel.size)


@dataclass(frozen=True)
class PeriodicStimulus:
    """A pulse train into chosen channels: `count` pulses every `period_ms` from `start_ms`.

    The paper's validation protocol is `PeriodicStimulus([n], 100.0, 10.0, 5000.0, start_ms, count)`
    (10 ms, 100 µA, 0.2 Hz).

    Parameters
    ----------
    channels : int or sequence of int
        The channels every pulse goes into (not empty).
    amplitude_ua, width_ms : float
        Each pulse (width >= 0).
    period_ms : float
        Time between onsets (> 0).
    start_ms : float
        Absolute simulated time of the first onset (>= 0).
    count : int
        Number of pulses (>= 0).
    """

    channels: tuple[int, ...]
    amplitude_ua: float
    width_ms: float
    period_ms: float
    start_ms: float = 0.0
    count: int = 1

    def __post_init__(self) -> None:
        object.__setattr__(self, "channels", tuple(int(c) for c in np.atleast_1d(self.channels)))
        if not self.channels:
            raise PulseError("PeriodicStimulus.channels must not be empty")
        if self.width_ms < 0:
            raise PulseError(f"PeriodicStimulus.width_ms must be >= 0, got {self.width_ms}")
        if self.period_ms <= 0:
            raise PulseError(f"PeriodicStimulus.period_ms must be > 0, got {self.period_ms}")
        if self.count < 0:
            raise PulseError(f"PeriodicStimulus.count must be >= 0, got {self.count}")
        if self.start_ms < 0:
            raise PulseError(f"PeriodicStimulus.start_ms must be >= 0, got {self.start_ms}")

    def onsets_ms(self) -> np.ndarray:
        """The onsets of the train.

        Returns
        -------
        float64[count]
            Absolute simulated time of every pulse's onset (ms).
        """
        return self.start_ms + self.period_ms * np.arange(self.count, dtype=np.float64)

    def pulses_between(self, t0_ms: float, t1_ms: float) -> Pulses:
        """The pulses of the train that start in a window, for a `Network.run` call.

        Parameters
        ----------
        t0_ms, t1_ms : float
            The window [t0_ms, t1_ms) in absolute simulated time; t0_ms is where the `run`
            call starts.

        Returns
        -------
        Pulses
            One pulse per channel per onset in the window, onsets relative to ``t0_ms``.
        """
        on = self.onsets_ms()
        on = on[(on >= t0_ms - 1e-9) & (on < t1_ms - 1e-9)]
        k = len(self.channels)
        return Pulses(
            channel=np.tile(np.array(self.channels, dtype=np.uint32), on.size),
            amplitude_ua=np.full(on.size * k, self.amplitude_ua),
            width_ms=np.full(on.size * k, self.width_ms),
            onset_ms=np.repeat(np.maximum(on - t0_ms, 0.0), k),
        )
