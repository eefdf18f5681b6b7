"""The stop guard on its own: a socket stands for the device's connection."""

from __future__ import annotations

import os
import signal
import socket
import subprocess

import pytest

from adapters.guard import GuardLost, StopGuard
from tests.harness import wait_for


@pytest.fixture
def line():
    """The device's end and the adapter's end of a connection."""
    device, adapter = socket.socketpair()
    device.settimeout(5.0)
    yield device, adapter
    device.close()
    adapter.close()


def test_an_adapter_that_ends_unreleased_gets_its_device_stopped(line):
    device, adapter = line
    guard = StopGuard(adapter.fileno(), b"STOP\n", "the test device", "STOP")
    guard.abandon()  # as the adapter's death closes the pipe
    assert device.recv(16) == b"STOP\n"
    assert guard.process.wait(timeout=5) == 0


def test_a_released_guard_ends_without_writing(line):
    device, adapter = line
    guard = StopGuard(adapter.fileno(), b"STOP\n", "the test device", "STOP")
    guard.release()
    assert guard.process.returncode == 0
    device.settimeout(0.2)
    with pytest.raises(TimeoutError):
        device.recv(16)


@pytest.mark.parametrize("freeze_s", [0.0, 5.0])
def test_a_guard_lost_while_the_adapter_lives_is_replaced_at_the_next_beat(line, freeze_s):
    device, adapter = line
    guard = StopGuard(adapter.fileno(), b"STOP\n", "the test device", "STOP", freeze_s=freeze_s)
    first = guard.process
    os.kill(first.pid, signal.SIGKILL)
    wait_for(lambda: first.poll() is not None, 5.0)
    assert guard.beat() is False  # not a stop: a new guard
    assert guard.process is not first and guard.process.poll() is None
    assert guard.replaced == 1
    guard.abandon()  # and the adapter's death is still covered
    assert device.recv(16) == b"STOP\n"


def test_a_guard_that_cannot_be_replaced_is_a_device_fault(line, monkeypatch):
    _, adapter = line
    guard = StopGuard(adapter.fileno(), b"STOP\n", "the test device", "STOP")
    os.kill(guard.process.pid, signal.SIGKILL)
    wait_for(lambda: guard.process.poll() is not None, 5.0)

    def no_more_processes(*args, **kwargs):
        raise OSError(11, "Resource temporarily unavailable")

    monkeypatch.setattr(subprocess, "Popen", no_more_processes)
    with pytest.raises(GuardLost, match=r"the stop guard of the test device \(pid \d+\) ended"):
        guard.beat()
