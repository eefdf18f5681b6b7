"""A stop request may be made from a signal handler, however often, whatever the process
was doing."""

import os
import signal
import threading
import time

from hub.stopping import StopFlag


def test_it_waits_until_set_or_for_its_timeout():
    flag = StopFlag()
    t0 = time.monotonic()
    assert flag.wait(0.05) is False and time.monotonic() - t0 >= 0.05
    threading.Timer(0.05, flag.set).start()
    assert flag.wait(5.0) is True and flag.is_set()


def test_signals_that_come_inside_each_others_handlers_still_stop_it():
    flag = StopFlag()
    depth = []

    def handler(*_):
        depth.append(len(depth))
        if len(depth) < 3:  # a second and a third signal, each inside the handler before
            os.kill(os.getpid(), signal.SIGUSR1)
        flag.set()

    previous = signal.signal(signal.SIGUSR1, handler)
    try:
        threading.Timer(0.02, os.kill, (os.getpid(), signal.SIGUSR1)).start()
        assert flag.wait(5.0)  # the handlers ran inside this wait, one inside another
    finally:
        signal.signal(signal.SIGUSR1, previous)
    assert depth == [0, 1, 2]
