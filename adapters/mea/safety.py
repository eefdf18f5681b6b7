"""Stimulation safety for a living culture: every pulse checked, none clipped.

A hub pulse (``Stimulation``: amplitude ``A`` µA, width ``W`` ms, monophasic in the
contract) becomes one **charge-balanced biphasic** pulse here: two phases of ``A`` µA and
``W/2`` each, the negative (cathodic) one first by default — the same total duration as the
simulated culture's pulse, with no net charge. It is then checked against the limits; one
that breaks any of them is **refused** (logged with its reason, counted by reason), never
clipped to fit:

- the electrode is one of the layout's (``channel``);
- 0 ≤ amplitude ≤ ``max_amplitude_ua`` (the amplitude is the pulse's size: its polarity is
  ``polarity``, so a negative one is refused, not taken past the charge check);
- each phase ≤ ``max_phase_us`` and ≥ ``min_phase_us``;
- charge per phase ``A · W/2`` ≤ the electrode's safe charge: ``max_charge_density_mc_per_cm2``
  (23 mC/cm² for titanium nitride) × its area (``electrode_diameter_um``: 30 µm → 163 nC);
- pulses per electrode ≤ ``max_pulse_hz`` over the last second, and all electrodes together ≤
  ``max_total_hz``.

Monophasic or voltage-mode stimulation cannot be configured at all (``shape`` and
``mode`` accept one value each): titanium-nitride electrodes must not be driven positive.
"""

from __future__ import annotations

import logging
import math
from collections import Counter, deque
from dataclasses import dataclass

from hub.config import ConfigError, check_value
from hub.limits import RATE_WINDOW_S, over, under

log = logging.getLogger(__name__)

POLARITIES = ("negative_first", "positive_first")


@dataclass(frozen=True)
class PulseLimits:
    """What a pulse may be (``[culture.params.safety]``); the defaults are conservative."""

    max_amplitude_ua: float = 100.0
    max_phase_us: float = 400.0
    min_phase_us: float = 20.0
    electrode_diameter_um: float = 30.0
    max_charge_density_mc_per_cm2: float = 23.0
    max_pulse_hz: float = 20.0
    max_total_hz: float = 200.0
    polarity: str = "negative_first"

    @property
    def max_charge_nc(self) -> float:
        """The electrode's safe charge per phase (nC): density × area."""
        area_cm2 = math.pi * (self.electrode_diameter_um / 2 * 1e-4) ** 2
        return self.max_charge_density_mc_per_cm2 * area_cm2 * 1e6

    @classmethod
    def from_params(cls, params: dict, key: str = "culture.params.safety") -> PulseLimits:
        """Read ``[culture.params.safety]``.

        Parameters
        ----------
        params : dict
            The table: the limits' keys (absent ones take the defaults), and ``shape`` and
            ``mode``, which may only say ``"biphasic"`` and ``"current"``.
        key : str
            The table's dotted key, for the messages.

        Raises
        ------
        ConfigError
            Naming ``<key>.<name>``: an unknown key, a limit that is not a number > 0,
            another shape, mode or polarity, ``min_phase_us`` over ``max_phase_us``.
        """
        params = dict(params)
        for name, only in (("shape", "biphasic"), ("mode", "current")):
            value = params.pop(name, only)
            if value != only:
                raise ConfigError(
                    f"{key}.{name} must be {only!r}, got {value!r}: only charge-balanced "
                    "biphasic current pulses are delivered (a titanium-nitride electrode must "
                    "never be driven positive in voltage mode)"
                )
        unknown = sorted(set(params) - set(cls.__dataclass_fields__))
        if unknown:
            raise ConfigError(f"{key}: unknown key(s) {unknown}")
        out = {}
        for name, value in params.items():
            if name == "polarity":
                if value not in POLARITIES:
                    raise ConfigError(f"{key}.polarity must be one of {POLARITIES}")
                out[name] = value
            else:
                out[name] = check_value(f"{key}.{name}", float, value, gt=0)
        limits = cls(**out)
        if limits.min_phase_us > limits.max_phase_us:
            raise ConfigError(f"{key}.min_phase_us must be <= max_phase_us")
        return limits


@dataclass(frozen=True)
class BiphasicPulse:
    """One pulse as the instrument delivers it."""

    channel: int
    amplitude_ua: float
    phase_us: float
    negative_first: bool


class SafetyGate:
    """Checks pulses against :class:`PulseLimits`, counting refusals by reason.

    Parameters
    ----------
    limits : PulseLimits
    n_channels : int, optional
        The layout's electrodes (channels ``0..n_channels-1``); a pulse on any other is
        refused (``channel``). None: not checked.
    """

    def __init__(self, limits: PulseLimits, n_channels: int | None = None):
        self.limits = limits
        self.n_channels = n_channels
        self.refused: Counter[str] = Counter()
        self.admitted = 0
        self._per_channel: dict[int, deque[float]] = {}
        self._all: deque[float] = deque()

    def admit(self, channel: int, amplitude_ua: float, width_ms: float, t_s: float):
        """The biphasic pulse for a hub pulse, or why it is refused.

        An admitted pulse counts towards the rates of the next second; a refused one does
        not. Not thread-safe: one caller at a time.

        Parameters
        ----------
        channel : int
            The electrode's channel id.
        amplitude_ua : float
            The pulse's amplitude, µA (each phase's).
        width_ms : float
            The hub pulse's width, ms: the two phases together.
        t_s : float
            Its onset, s (run time), for the rate limits.

        Returns
        -------
        BiphasicPulse or str
            The pulse to deliver, or ``"<reason>: <detail>"`` (the reason as counted in
            :attr:`refused`).
        """
        lim = self.limits
        phase_us = width_ms * 1e3 / 2
        charge_nc = amplitude_ua * phase_us * 1e-3
        reason = None
        if self.n_channels is not None and not 0 <= channel < self.n_channels:
            reason = (
                "channel",
                f"channel {channel}: the layout has channels 0..{self.n_channels - 1}",
            )
        elif not amplitude_ua >= 0:
            reason = ("amplitude", f"{amplitude_ua:g} µA < 0: the amplitude is the pulse's size "
                      "(its polarity is safety.polarity)")  # fmt: skip
        elif over(amplitude_ua, lim.max_amplitude_ua):
            reason = (
                "amplitude",
                f"{amplitude_ua:g} µA > max_amplitude_ua {lim.max_amplitude_ua:g}",
            )
        elif over(phase_us, lim.max_phase_us):
            reason = ("phase", f"phase {phase_us:g} µs > max_phase_us {lim.max_phase_us:g}")
        elif under(phase_us, lim.min_phase_us):
            reason = ("phase", f"phase {phase_us:g} µs < min_phase_us {lim.min_phase_us:g}")
        elif charge_nc > lim.max_charge_nc:
            reason = ("charge", f"{charge_nc:.1f} nC per phase > {lim.max_charge_nc:.1f} nC safe "
                      f"for a {lim.electrode_diameter_um:g} µm electrode")  # fmt: skip
        else:
            recent = self._per_channel.setdefault(channel, deque())
            for q in (recent, self._all):
                while q and q[0] <= t_s - RATE_WINDOW_S:
                    q.popleft()
            if len(recent) + 1 > lim.max_pulse_hz:
                reason = ("rate", f"channel {channel}: over max_pulse_hz {lim.max_pulse_hz:g}")
            elif len(self._all) + 1 > lim.max_total_hz:
                reason = ("total_rate", f"all channels: over max_total_hz {lim.max_total_hz:g}")
        if reason is not None:
            kind, detail = reason
            if not self.refused[kind]:
                log.warning("pulse refused (%s): %s", kind, detail)
            self.refused[kind] += 1
            return f"{kind}: {detail}"
        recent.append(t_s)
        self._all.append(t_s)
        self.admitted += 1
        return BiphasicPulse(channel, amplitude_ua, phase_us, lim.polarity == "negative_first")
