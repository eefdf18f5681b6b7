"""A hub in the test process and endpoints as subprocesses, over real Zenoh on loopback."""

from __future__ import annotations

import os
import threading
import time
from contextlib import contextmanager

import pytest

from hub.bus import open_session
from hub.config import load_config
from hub.launch import start_local_endpoints, stop_local_endpoints
from hub.loop import Hub
from hub.record import read_run
from tests.conftest import TEST_ENDPOINTS


class Harness:
    """A hub in this process and the test endpoints as subprocesses."""

    def __init__(self, tmp_path, overrides):
        self.overrides = TEST_ENDPOINTS + overrides
        self.cfg = load_config(None, self.overrides)
        self.run_dir = tmp_path / "run"
        self.run_dir.mkdir()
        self.procs = start_local_endpoints(None, self.overrides, self.cfg, tmp_path)
        self.hub = None

    def run(self, progress=None, **hub_options):
        self.hub = Hub(self.cfg, run_dir=self.run_dir, progress=progress, **hub_options)
        self.result = self.hub.run()
        self.record = read_run(self.run_dir)
        return self.result

    def pid(self, role):
        return next(p.popen.pid for p in self.procs if p.role == role)

    def sent(self, kind):
        return {m.step: m for m in self.record.decoded(kind, "tx")}

    def received(self, kind):
        return {m.step: m for m in self.record.decoded(kind, "rx")}


@contextmanager
def harness(tmp_path, bus_overrides, *overrides):
    h = Harness(tmp_path, bus_overrides + list(overrides))
    try:
        yield h
    finally:
        h.exit_codes = stop_local_endpoints(h.procs)


@contextmanager
def subscribed(bus, key: str, callback):
    """A subscriber to ``key`` calling ``callback(sample)`` for the ``with`` block, from a
    session of its own opened as soon as the hub listens (in a thread: the hub of a
    harness starts inside the block)."""
    done = threading.Event()

    def subscriber():
        session = open_session(bus, listener=False)
        sub = session.declare_subscriber(key, callback)
        done.wait(60)
        sub.undeclare()
        session.close()

    thread = threading.Thread(target=subscriber)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join(30)


def wait_for(condition, timeout_s=10.0):
    """Wait until ``condition()`` holds (polling); fail the test after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("condition not reached in time")
        time.sleep(0.01)


def _fifo_permitted() -> bool:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except (AttributeError, OSError):
        return False
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return True


needs_fifo = pytest.mark.skipif(
    not _fifo_permitted(), reason="SCHED_FIFO not permitted here (needs CAP_SYS_NICE)"
)
