"""Is a reply what its endpoint should send? Its content checked, with no bus and no clock.

:class:`ReplyChecker` decodes a reply and checks it against the schema, the run (its id),
the step's window, and what its endpoint described (a body's sensor count and range, a
culture's channels). Whether the reply comes at the right time — the step the loop waits
for, before its deadline — is the scheduler's business, not this module's.
"""

from __future__ import annotations

import numpy as np

from hub.protocol import (
    OUTPUT_TYPE,
    SMALL_ARRAY,
    WINDOW_TOLERANCE_S,
    Description,
    Message,
    ProtocolError,
    StepWindow,
    kernels,
)

# The largest table of known channels, one byte a channel number: larger numbers go to a set.
_MAX_TABLE_BYTES = 1 << 20
_bounds_s = StepWindow.bounds_s


class ReplyChecker:
    """Checks replies of one run against the run and the endpoints' descriptions.

    Parameters
    ----------
    run : str
        The run id every reply must carry.
    period_s : float
        The run's period: step k's window is ``[k·T, (k+1)·T)``.
    """

    def __init__(self, run: str, period_s: float):
        self.run = run
        self.period_s = period_s
        self._n_sensors: int | None = None
        self._max_range_m = np.inf  # with a hair of tolerance for float32 readings
        self._known_channels: frozenset[int] | None = None
        self._known_channel: np.ndarray | None = None  # lookup table by channel id
        kernels()  # the checks of larger arrays compiled before the run, not in it

    def take_description(self, desc: Description) -> None:
        """What an endpoint said of itself: what its replies are checked against."""
        if desc.role == "culture":
            self._known_channels = frozenset(desc.channel.tolist())
            top = int(desc.channel.max(initial=0))
            # a table by channel number, unless the numbers are too large for one (the set
            # then checks every reply)
            self._known_channel = None if top >= _MAX_TABLE_BYTES else np.zeros(top + 1, bool)
            if self._known_channel is not None:
                self._known_channel[desc.channel] = True
        else:
            self._n_sensors = desc.n_sensors
            self._max_range_m = desc.max_range_m * (1 + 1e-6)

    def check(self, role: str, raw: bytes) -> Message:
        """The reply of ``role`` decoded, if its content is right.

        Parameters
        ----------
        role : str
            Who sent it: ``"body"`` (a SensorReading) or ``"culture"`` (a SpikeBatch).
        raw : bytes
            The reply's payload, unsealed and whole.

        Raises
        ------
        ProtocolError
            With the drop's kind: the schema's kinds, ``foreign`` (another run),
            ``window`` (not its step's window), ``array``/``range`` (unlike the endpoint's
            description).
        """
        message = OUTPUT_TYPE[role].decode(raw)
        if message.run != self.run:
            raise ProtocolError("foreign", f"reply of run {message.run!r}")
        step = message.step
        t0_s, t1_s = _bounds_s(step, self.period_s)
        if role == "culture":
            if (
                abs(message.t0_s - t0_s) > WINDOW_TOLERANCE_S
                or abs(message.t1_s - t1_s) > WINDOW_TOLERANCE_S
            ):
                raise ProtocolError(
                    "window", f"spikes of step {step} over [{message.t0_s}, {message.t1_s})"
                )
            self._check_channels(message.channel)
        else:
            if message.t_s > t1_s + WINDOW_TOLERANCE_S:
                raise ProtocolError("window", f"reading of step {step} taken at {message.t_s} s")
            self._check_ranges(message.ranges_m)
        return message

    def _check_ranges(self, ranges: np.ndarray) -> None:
        if self._n_sensors is None:
            return
        if ranges.size != self._n_sensors:
            raise ProtocolError(
                "array", f"ranges_m has {ranges.size} values, body has {self._n_sensors}"
            )
        if ranges.size and max(ranges.tolist()) > self._max_range_m:
            described = self._max_range_m / (1 + 1e-6)
            raise ProtocolError("range", f"ranges_m exceeds max_range_m {described:g}")

    def _check_channels(self, channel: np.ndarray) -> None:
        if self._known_channels is None or not channel.size:
            return
        if channel.size <= SMALL_ARRAY or self._known_channel is None:
            ok = self._known_channels.issuperset(channel.tolist())  # plain Python beats numpy
        else:
            ok = kernels().all_known(channel, self._known_channel)
        if not ok:
            raise ProtocolError("range", "spikes on channels the culture does not have")
