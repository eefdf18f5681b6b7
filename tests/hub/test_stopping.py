"""A stop request may be made from a signal handler, however often, whatever the process
was doing."""

import os
import resource
import signal
import threading
import time

import pytest

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


def _sleeping(native_id: int) -> bool:
    with open(f"/proc/self/task/{native_id}/stat") as f:
        return f.read().rsplit(")", 1)[1].split()[0] == "S"


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="thread states: Linux")
def test_every_thread_that_waits_wakes_when_it_is_set():
    flag = StopFlag()
    woke, ids = [], []

    def waiter():
        ids.append(threading.get_native_id())
        woke.append(flag.wait(5.0))

    waiters = [threading.Thread(target=waiter) for _ in range(3)]
    for thread in waiters:
        thread.start()
    deadline = time.monotonic() + 5.0  # until all three are asleep in their wait
    while not (len(ids) == 3 and all(map(_sleeping, ids))) and time.monotonic() < deadline:
        time.sleep(0.001)
    assert len(ids) == 3 and all(map(_sleeping, ids))
    t0 = time.monotonic()
    flag.set()
    for thread in waiters:
        thread.join()
    assert woke == [True, True, True] and time.monotonic() - t0 < 1.0
    assert flag.wait(0.0) is True  # and stays set


@pytest.mark.skipif(not hasattr(resource, "RUSAGE_THREAD"), reason="per-thread counts: Linux")
def test_waiting_does_not_wake_up_to_look():
    """The flag is not polled: a waiting thread sleeps until set or timed out (an
    endpoint's main thread waits this way beside the loop's callback thread)."""
    flag = StopFlag()
    switches = resource.getrusage(resource.RUSAGE_THREAD).ru_nvcsw
    t0 = time.monotonic()
    assert flag.wait(0.3) is False
    assert time.monotonic() - t0 >= 0.3
    slept = resource.getrusage(resource.RUSAGE_THREAD).ru_nvcsw - switches
    assert slept <= 5  # a 5 ms poll sleeps and wakes ~60 times
