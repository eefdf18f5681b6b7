"""A stop request that a signal handler may make.

``threading.Event.set`` takes the event's lock: a signal handler that calls it while the
interrupted code holds that lock (inside ``wait`` or another ``set``: a second SIGTERM
during the first one's handler) waits for itself forever. A process seen stuck that way
at its end is why this exists. :class:`StopFlag` is a plain flag, set and read without a
lock; :meth:`StopFlag.wait` looks at it every few milliseconds.
"""

from __future__ import annotations

import time

POLL_S = 0.005  # how often wait() looks at the flag


class StopFlag:
    """``set()``, ``is_set()`` and ``wait(timeout)`` like ``threading.Event``, safe to set
    from a signal handler (and from any thread)."""

    def __init__(self):
        self._set = False

    def set(self) -> None:
        self._set = True

    def is_set(self) -> bool:
        return self._set

    def wait(self, timeout_s: float) -> bool:
        """Return True once set, False after ``timeout_s`` without it."""
        deadline = time.monotonic() + timeout_s
        while not self._set:
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            time.sleep(min(left, POLL_S))
        return True
