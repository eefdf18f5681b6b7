"""A stop request that a signal handler may make.

``threading.Event.set`` takes the event's lock: a signal handler that calls it while the
interrupted code holds that lock (inside ``wait`` or another ``set``: a second SIGTERM
during the first one's handler) waits for itself forever. A process seen stuck that way
at its end is why this exists. :class:`StopFlag` is a plain flag, set and read without a
lock; :meth:`StopFlag.wait` sleeps on a pipe that ``set`` writes a byte to (a self-pipe:
no lock anywhere, and no waking up to look at the flag, which an endpoint's main thread
did 200 times a second, each time taking the interpreter from the loop's callback thread).
"""

from __future__ import annotations

import os
import select
import time


class StopFlag:
    """``set()``, ``is_set()`` and ``wait(timeout)`` like ``threading.Event``, safe to set
    from a signal handler (and from any thread)."""

    def __init__(self):
        self._set = False
        self._read_fd, self._write_fd = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)

    def __del__(self):
        for fd in (getattr(self, "_read_fd", None), getattr(self, "_write_fd", None)):
            if fd is not None:
                os.close(fd)

    def set(self) -> None:
        """Set the flag and wake every :meth:`wait` (no lock: safe in a signal handler)."""
        self._set = True
        try:
            os.write(self._write_fd, b"\0")
        except BlockingIOError:  # the pipe is full of earlier sets: the waiter wakes anyway
            pass

    def is_set(self) -> bool:
        """Whether the flag was set."""
        return self._set

    def wait(self, timeout_s: float) -> bool:
        """Return True once set, False after ``timeout_s`` without it."""
        deadline = time.monotonic() + timeout_s
        while not self._set:
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            # Never drained: once set, the pipe stays readable for every waiting thread.
            select.select([self._read_fd], [], [], left)
        return True


# A stop signal (Ctrl-C, or the runner's SIGTERM) that came while a command was starting up,
# before its own handler was in. The KeyboardInterrupt raised for it stops the start-up
# where it is, unless third-party code swallows it: one raised inside a ctypes callback
# (numba loading its cache through llvmlite) is printed as "ignored" and lost, and the
# endpoint would go on to serve. The command's own handler, once in, looks here.
_signalled_while_starting = False


def interrupt_while_starting(signum, frame) -> None:
    """Signal handler for a command's start-up: remember the signal, raise KeyboardInterrupt.

    Parameters
    ----------
    signum : int
        The signal (not used: any stop signal counts).
    frame : frame or None
        The interrupted frame (not used).
    """
    global _signalled_while_starting
    _signalled_while_starting = True
    raise KeyboardInterrupt


def signalled_while_starting() -> bool:
    """Whether a stop signal came during this command's start-up (even one swallowed)."""
    return _signalled_while_starting


def forget_start_signal() -> None:
    """Forget any such signal: a command starts, or ended (``neuvision`` may be called more
    than once in one process)."""
    global _signalled_while_starting
    _signalled_while_starting = False


def quiet_terminal() -> None:
    """After SIGHUP (the terminal closed): what would go to it goes nowhere, so that a
    progress line or the run's last line cannot fail on a terminal that is gone (the run's
    record and logs say it all)."""
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        for fd in (1, 2):
            if os.isatty(fd):
                os.dup2(null, fd)
    finally:
        os.close(null)
