"""A device's last stop when its adapter's process dies without making it safe.

The endpoints make their devices safe in their own process (hub/endpoint.py,
docs/safety.md): a SIGKILL, the OOM killer or a crash in native code runs none of it, and
neither a Khepera's serial protocol nor an RHX's stimulation has a watchdog of its own.
:class:`StopGuard` is a small process, started once the device's connection is open,
that shares that connection's open file (a serial port's, a TCP socket's) and a pipe
with the adapter. When the adapter's process ends without :meth:`StopGuard.release` —
whatever ends it — the pipe reaches its end and the guard writes the device's stop on the
connection, says so on its standard error (the endpoint's log) and ends. A clean exit
releases it first: it then ends without writing. It runs in a session of its own, so that
a signal to the adapter's process group does not take it too.

It cannot help when the adapter's process is frozen (``SIGSTOP``, a debugger) rather than
ended, nor when the host stops.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys

log = logging.getLogger(__name__)

#: The guard's program (``python -I -S -c``: it starts in tens of ms): argv[1] the
#: connection's file descriptor, argv[2] the read end of the adapter's pipe, argv[3] the
#: stop (hex), argv[4] what it stops, argv[5] the stop in words. It waits for a release
#: byte or the pipe's end, and writes only on the end.
_PROGRAM = r"""
import os, select, signal, sys, termios, time
signal.signal(signal.SIGINT, signal.SIG_IGN)
fd, pipe, what, words = int(sys.argv[1]), int(sys.argv[2]), sys.argv[4], sys.argv[5]
stop = bytes.fromhex(sys.argv[3])
try:
    released = os.read(pipe, 1) == b"r"
except OSError:
    released = False
if not released:
    data, deadline = stop, time.monotonic() + 1.0
    try:
        while data and time.monotonic() < deadline:
            select.select([], [fd], [], 0.1)
            try:
                data = data[os.write(fd, data):]
            except BlockingIOError:
                pass
        if os.isatty(fd):
            termios.tcdrain(fd)  # on the wire before the port closes
        done = "sent" if not data else "not all sent in 1 s"
    except (OSError, termios.error) as exc:
        done = f"could not be sent ({exc})"
    print(f"neuvision: stop guard: the adapter of {what} ended without making it safe; "
          f"{words} {done}", file=sys.stderr, flush=True)
"""


class StopGuard:
    """Writes ``stop`` on the open file ``fd`` if this process dies without :meth:`release`.

    Parameters
    ----------
    fd : int
        The device connection's file descriptor (shared with the guard, not duplicated:
        the line's settings stay the adapter's).
    stop : bytes
        What makes the device safe, as written on the connection (start it with a line
        end, so that a command the adapter was cut off in does not swallow it).
    what : str
        The device, for the guard's message (``khepera on /dev/ttyUSB0``).
    words : str
        The stop, for the message (``D,0,0``).
    """

    def __init__(self, fd: int, stop: bytes, what: str, words: str):
        read_end, self._pipe = os.pipe()
        try:
            self.process = subprocess.Popen(
                [sys.executable, "-I", "-S", "-c", _PROGRAM, str(fd), str(read_end),
                 stop.hex(), what, words],
                pass_fds=(fd, read_end), stdin=subprocess.DEVNULL, start_new_session=True,
            )  # fmt: skip
        except BaseException:
            os.close(self._pipe)
            raise
        finally:
            os.close(read_end)

    def release(self) -> None:
        """The adapter made the device safe itself (or could not) and lets it go: the guard
        ends without writing."""
        if self._pipe < 0:
            return
        try:
            os.write(self._pipe, b"r")
        except OSError:
            pass
        os.close(self._pipe)
        self._pipe = -1
        try:
            self.process.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            log.warning("the stop guard (pid %d) did not end", self.process.pid)

    def abandon(self) -> None:
        """As the adapter's death does: the pipe closed unreleased (tests)."""
        if self._pipe >= 0:
            os.close(self._pipe)
            self._pipe = -1
