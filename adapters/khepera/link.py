"""The serial link to a Khepera: one command, one checked reply, at the link's own pace.

:class:`SerialLink` drains stale input before each command, waits for the reply and checks
it (:func:`~adapters.khepera.protocol.parse_reply`). A truncated, garbled or out-of-order
line is logged with its bytes, counted, and the link resynchronised (input drained, the
command sent again); it is never parsed as data. A link with no valid reply for
``silent_s`` is a fault (:class:`LinkFault`), and so is a port that fails.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter

import serial

from adapters.guard import StopGuard
from adapters.khepera.protocol import Reply, ReplyError, command, parse_reply
from hub.endpoint import DeviceFault

log = logging.getLogger(__name__)

#: the bauds a Khepera II's jumpers select
BAUDS = (9600, 19200, 38400, 57600, 115200)


class LinkFault(DeviceFault):
    """The serial link cannot be used: silent for too long, or the port failed."""


def byte_time_s(baud: int, stop_bits: int = 2) -> float:
    """Seconds one byte takes on the wire: a start bit, 8 data bits, the stop bits.

    Parameters
    ----------
    baud : int
        The line's speed (bits/s).
    stop_bits : int
        1 or 2.
    """
    return (1 + 8 + stop_bits) / baud


class SerialLink:
    """Commands and checked replies over one serial port (thread-safe).

    Parameters
    ----------
    port : serial.Serial
        Open, 8 data bits, no parity (:func:`open_port`).
    timeout_s : float
        How long to wait for one reply line.
    silent_s : float
        With no valid reply for this long the link is a fault.
    dialect : str
        ``khepera2`` or ``khepera3``.
    tries : int
        Attempts per command before its failure is handed to the caller.
    """

    def __init__(
        self,
        port: serial.Serial,
        *,
        timeout_s: float = 0.2,
        silent_s: float = 1.0,
        dialect: str = "khepera2",
        tries: int = 3,
    ):
        self.port = port
        self.port.timeout = timeout_s
        self.timeout_s = timeout_s
        self.silent_s = silent_s
        self.dialect = dialect
        self.tries = tries
        self.counts: Counter[str] = Counter()  # replies, and faults by kind
        self._lock = threading.Lock()
        self._last_valid = time.monotonic()
        self._rx = b""  # bytes read past the last line taken
        self.guard: StopGuard | None = None

    @property
    def name(self) -> str:
        """The port's device path, for messages."""
        return str(self.port.port)

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` released the port."""
        return not self.port.is_open

    def transact(self, letter: str, *values: int) -> Reply:
        """Send one command and return its checked reply.

        Stale input is drained first; a failed reply is retried (the command sent again).
        Callers on several threads take turns.

        Parameters
        ----------
        letter : str
            The command's letter.
        *values : int
            Its arguments (:func:`~adapters.khepera.protocol.command`).

        Raises
        ------
        ReplyError
            No valid reply in ``tries`` attempts (each failure counted and logged).
        LinkFault
            The port failed, or no valid reply came for ``silent_s``.
        """
        raw = command(letter, *values, dialect=self.dialect)
        with self._lock:
            if self.closed:  # pyserial would fail on it with a TypeError, not an OSError
                raise LinkFault(f"serial link {self.name} is closed")
            error: ReplyError | None = None
            for _ in range(self.tries):
                try:
                    reply = self._exchange(letter, raw)
                except ReplyError as exc:
                    error = exc
                    self._note(exc)
                    if time.monotonic() - self._last_valid > self.silent_s:
                        raise LinkFault(
                            f"serial link {self.name} silent: no valid reply for "
                            f"{self.silent_s} s (last: {exc})"
                        ) from None
                    continue
                self._last_valid = time.monotonic()
                self.counts["replies"] += 1
                return reply
            raise error

    def _exchange(self, letter: str, raw: bytes) -> Reply:
        try:
            stale = self.port.in_waiting
            junk, self._rx = self._rx + (self.port.read(stale) if stale else b""), b""
            if junk:
                self.counts["stale_bytes"] += len(junk)
                log.debug("drained %d stale bytes %r before %r", len(junk), junk, raw)
            self.port.write(raw)
            deadline = time.monotonic() + self.timeout_s
            while True:
                line = self._readline()
                try:
                    return parse_reply(letter, line, dialect=self.dialect)
                except ReplyError as exc:
                    # A late reply to an earlier command: its own reply may still follow.
                    if exc.kind != "order" or time.monotonic() >= deadline:
                        raise
                    self._note(exc)
        except (serial.SerialException, OSError) as exc:
            raise LinkFault(f"serial link {self.name} failed: {exc}") from None

    def _readline(self) -> bytes:
        """The next line (through ``\n``), or what came before the port's timeout. Reads
        what is waiting at once (pyserial's ``readline`` makes a system call per byte)."""
        while b"\n" not in self._rx:
            chunk = self.port.read(self.port.in_waiting or 1)  # waits up to the timeout
            if not chunk:
                line, self._rx = self._rx, b""
                return line
            self._rx += chunk
        line, _, self._rx = self._rx.partition(b"\n")
        return line + b"\n"

    def _note(self, exc: ReplyError) -> None:
        if exc.kind == "truncated" and not exc.line:
            kind = "timeout"
        else:
            kind = exc.kind
        self.counts[kind] += 1
        log.warning("serial link %s: %s", self.name, exc)

    def guard_motors(self, freeze_s: float = 0.0) -> None:
        """Start a :class:`~adapters.guard.StopGuard` on this port: the motors stopped if
        this process dies without closing the link (a Khepera has no watchdog of its own),
        and, with ``freeze_s``, if :meth:`beat` stops coming for that long. Released by
        :meth:`close`."""
        if self.guard is None:
            stop = command("D", 0, 0, dialect=self.dialect)
            self.guard = StopGuard(
                self.port.fd, b"\r" + stop, f"the khepera on {self.name}",
                f"{stop.strip().decode()} on {self.name}", freeze_s=freeze_s,
            )  # fmt: skip

    def beat(self) -> bool:
        """Tell the stop guard this process lives (once a cycle); True when the guard
        stopped the motors since the last beat (this process was frozen)."""
        return self.guard is not None and self.guard.beat()

    def rest(self) -> None:
        """The beats stop on purpose (the serial thread ends): the guard stands by for
        this process's end only."""
        if self.guard is not None:
            self.guard.rest()

    def close(self) -> None:
        """Release the port (and its stop guard: the caller stopped the motors, or could
        not)."""
        if self.guard is not None:
            self.guard.release()
        with self._lock:  # not under a transaction of another thread's
            try:
                self.port.close()
            except (serial.SerialException, OSError):
                pass


def open_port(
    path: str, *, baud: int = 9600, stop_bits: int = 2, timeout_s: float = 0.2
) -> serial.Serial:
    """Open a Khepera's serial port: 8 data bits, no parity, no flow control.

    Parameters
    ----------
    path : str
        The device (``/dev/ttyUSB0``).
    baud : int
        The robot's baud (:data:`BAUDS` for a Khepera II's jumpers).
    stop_bits : int
        2, or anything else for 1.
    timeout_s : float
        How long a read or a write may wait.

    Raises
    ------
    LinkFault
        The port cannot be opened (named, with the system's reason).
    """
    try:
        return serial.Serial(
            path,
            baudrate=baud,
            bytesize=serial.EIGHTBITS,
            parity=serial.PARITY_NONE,
            stopbits=serial.STOPBITS_TWO if stop_bits == 2 else serial.STOPBITS_ONE,
            timeout=timeout_s,
            write_timeout=timeout_s,
            exclusive=True,
        )
    except (serial.SerialException, OSError, ValueError) as exc:
        raise LinkFault(f"cannot open serial port {path}: {exc}") from None
