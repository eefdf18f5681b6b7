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

With ``freeze_s`` it also watches the adapter's *life*: the adapter's thread that talks
to the device :meth:`~StopGuard.beat` s each cycle, and when no beat comes for
``freeze_s`` — the process frozen (``SIGSTOP``, a debugger, a swap storm) or that thread
hung — the guard writes the stop, says so, and tells the adapter through a second pipe
(:meth:`StopGuard.stopped`, read at its next beat, so that it sends its speeds again
rather than believe them applied). It then waits for beats again: a stall is survived,
an end is not.

A guard that ends while its adapter lives (killed by hand or by the OOM killer) would leave
the device unguarded; each beat looks, and a lost guard is replaced by a new one at once,
said in the log (:attr:`StopGuard.replaced`); one that cannot be replaced is a device fault
(:class:`GuardLost`), and the adapter makes the device safe and ends.

It cannot help when the host stops, nor when the guard itself is frozen with the adapter
(a ``SIGSTOP`` to both: it runs in a session of its own, so a signal to the adapter's
process group does not reach it).
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys

from hub.endpoint import DeviceFault

log = logging.getLogger(__name__)

#: The guard's program (``python -I -S -c``: it starts in tens of ms): argv[1] the
#: connection's file descriptor, argv[2] the read end of the adapter's pipe, argv[3] the
#: stop (hex), argv[4] what it stops, argv[5] the stop in words, argv[6] ``freeze_s``
#: (0: off), argv[7] the write end of the notice pipe (-1: none). It waits for a release
#: byte, the pipe's end, or (once a beat came) ``freeze_s`` without a beat.
_PROGRAM = r"""
import os, select, signal, sys, termios, time
signal.signal(signal.SIGINT, signal.SIG_IGN)
fd, pipe, what, words = int(sys.argv[1]), int(sys.argv[2]), sys.argv[4], sys.argv[5]
stop, freeze_s, notice = bytes.fromhex(sys.argv[3]), float(sys.argv[6]), int(sys.argv[7])

def send_stop():
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
        return "sent" if not data else "not all sent in 1 s"
    except (OSError, termios.error) as exc:
        return f"could not be sent ({exc})"

def say(text):
    print(f"neuvision: stop guard: {text}", file=sys.stderr, flush=True)

armed = frozen = False  # armed: beats come (the first arms it); frozen: they stopped
while True:
    ready, _, _ = select.select([pipe], [], [], freeze_s if armed else None)
    if not ready:
        armed, frozen = False, True
        say(f"the adapter of {what} gave no sign of life for {freeze_s:g} s (frozen or "
            f"hung); {words} {send_stop()}")
        try:
            os.write(notice, b"s")  # the adapter learns it when it beats again
        except OSError:
            pass
        continue
    try:
        data = os.read(pipe, 4096)
    except OSError:
        data = b""
    if b"r" in data:
        break  # released: the adapter made the device safe itself
    if not data:  # the pipe's end: the adapter's process is gone
        say(f"the adapter of {what} ended without making it safe; {words} {send_stop()}")
        break
    if data.endswith(b"p"):  # the beats stop on purpose (its link failed, it closes)
        armed = False
        continue
    if frozen:
        frozen = False
        say(f"the adapter of {what} is alive again")
    armed = freeze_s > 0
"""


class GuardLost(DeviceFault):
    """The stop guard ended while its adapter lives, and no new one could be started: the
    device would not be stopped if the adapter died now."""


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
    freeze_s : float
        Once the adapter has beaten (:meth:`beat`), this long without a beat writes the
        stop too; 0 (the default): only the adapter's end does.
    """

    def __init__(self, fd: int, stop: bytes, what: str, words: str, *, freeze_s: float = 0.0):
        if freeze_s < 0:
            raise ValueError("freeze_s must be >= 0")
        self.freeze_s = freeze_s
        self._args = (fd, stop, what, words)
        self.replaced = 0  # guards lost while the adapter lived, and replaced
        self._spawn()

    def _spawn(self) -> None:
        """Start the guard's process, with its pipes."""
        fd, stop, what, words = self._args
        freeze_s = self.freeze_s
        read_end, self._pipe = os.pipe()
        notice_read, notice_write = os.pipe() if freeze_s > 0 else (-1, -1)
        passed = (fd, read_end) if notice_write < 0 else (fd, read_end, notice_write)
        try:
            self.process = subprocess.Popen(
                [sys.executable, "-I", "-S", "-c", _PROGRAM, str(fd), str(read_end),
                 stop.hex(), what, words, repr(float(freeze_s)), str(notice_write)],
                pass_fds=passed, stdin=subprocess.DEVNULL, start_new_session=True,
            )  # fmt: skip
        except BaseException:
            os.close(self._pipe)
            self._pipe = -1
            if notice_read >= 0:
                os.close(notice_read)
            raise
        finally:
            os.close(read_end)
            if notice_write >= 0:
                os.close(notice_write)
        os.set_blocking(self._pipe, False)  # a beat never waits for a frozen guard
        self._notice = notice_read
        if notice_read >= 0:
            os.set_blocking(notice_read, False)

    def beat(self) -> bool:
        """The adapter lives (call it once per device cycle, from the thread that talks to
        the device). True when the guard stopped the device since the last beat: the
        adapter was frozen, and what it last sent no longer holds.

        Raises
        ------
        GuardLost
            The guard had ended, and no new one could be started.
        """
        if self._pipe < 0:
            return False
        if self.process.poll() is not None:
            self._replace()
        if self.freeze_s <= 0:
            return False
        try:
            os.write(self._pipe, b"h")
        except OSError:  # full (the guard frozen too) or gone (seen at the next beat)
            pass
        return self.stopped()

    def _replace(self) -> None:
        """The guard ended while the adapter lives: start another on the same connection."""
        lost, status = self.process.pid, self.process.returncode
        what = self._args[2]
        self._close_pipes()
        try:
            self._spawn()
        except OSError as exc:
            raise GuardLost(
                f"the stop guard of {what} (pid {lost}) ended (status {status}) and no new "
                f"one could be started ({exc}): the device would not be stopped if this "
                "process died"
            ) from None
        self.replaced += 1
        log.warning(
            "the stop guard of %s (pid %d) ended (status %s) while this process lives: a new "
            "one stands (pid %d)", what, lost, status, self.process.pid,
        )  # fmt: skip

    def rest(self) -> None:
        """The beats stop on purpose (the device's thread ends: its link failed, or the
        adapter closes): the guard watches only for the adapter's end until a beat comes
        again."""
        if self._pipe >= 0 and self.freeze_s > 0:
            try:
                os.write(self._pipe, b"p")
            except OSError:
                pass

    def stopped(self) -> bool:
        """Whether the guard stopped the device since the last call (``freeze_s``)."""
        if self._notice < 0:
            return False
        try:
            return bool(os.read(self._notice, 4096))
        except OSError:  # nothing to read (BlockingIOError), or gone
            return False

    def release(self) -> None:
        """The adapter made the device safe itself (or could not) and lets it go: the guard
        ends without writing."""
        if self._pipe < 0:
            return
        try:
            os.write(self._pipe, b"r")
        except OSError:
            pass
        self._close_pipes()
        try:
            self.process.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            log.warning("the stop guard (pid %d) did not end", self.process.pid)

    def abandon(self) -> None:
        """As the adapter's death does: the pipe closed unreleased (tests)."""
        self._close_pipes()

    def _close_pipes(self) -> None:
        for fd in (self._pipe, self._notice):
            if fd >= 0:
                os.close(fd)
        self._pipe = self._notice = -1
