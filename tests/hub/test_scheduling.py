"""Real-time scheduling of the hub's threads during realtime runs (hub/scheduling.py)."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import threading

import pytest

from hub.config import ConfigError
from hub.scheduling import (
    PM_QOS_DEVICE,
    available_cpus,
    check_cpus,
    endpoint_priority,
    hold_cpus_awake,
    place_threads,
    raise_threads,
    restore_placement,
    restore_threads,
)
from tests.harness import needs_fifo


def _policy(tid: int = 0) -> tuple[int, int]:
    """(policy without the reset-on-fork flag, priority) of one thread (0: this one)."""
    policy = os.sched_getscheduler(tid) & ~os.SCHED_RESET_ON_FORK
    return policy, os.sched_getparam(tid).sched_priority


def _policies() -> dict[int, tuple[int, int]]:
    out = {}
    for tid in map(int, os.listdir("/proc/self/task")):
        try:
            out[tid] = _policy(tid)
        except ProcessLookupError:
            pass
    return out


def _unchanged(before: dict[int, tuple[int, int]]) -> bool:
    """Every thread of ``before`` still alive has the policy it had then (a thread an
    earlier test or the test runner started may end meanwhile)."""
    now = _policies()
    return all(now[tid] == policy for tid, policy in before.items() if tid in now)


@needs_fifo
def test_raised_threads_run_fifo_and_are_put_back_afterwards():
    release = threading.Event()
    earlier = threading.Thread(target=release.wait, daemon=True)
    waiting = threading.Thread(target=release.wait, daemon=True)  # started once raised
    earlier.start()
    before = _policies()
    got = raise_threads(5)
    try:
        assert got.policy == "fifo" and got.priority == 5 and got.threads == len(before)
        during = _policies()
        assert all(during[tid] == (os.SCHED_FIFO, 5) for tid in before)
        # Neither a thread started meanwhile ...
        seen = {}
        later = threading.Thread(target=lambda: seen.update(policy=_policy()), daemon=True)
        later.start()
        later.join()
        assert seen["policy"] == (os.SCHED_OTHER, 0)
        # ... nor a child process inherits it.
        child = subprocess.run(
            [sys.executable, "-c", "import os; print(os.sched_getscheduler(0))"],
            capture_output=True,
            text=True,
            check=True,
        )
        assert int(child.stdout) == os.SCHED_OTHER
        # Threads started since are raised on request (zenoh-python's callback threads).
        waiting.start()
        assert _policy(waiting.native_id) == (os.SCHED_OTHER, 0)
        got.include_new_threads()
        assert _policy(waiting.native_id) == (os.SCHED_FIFO, 5)
    finally:
        restore_threads(got)
    after = _policies()
    assert all(after[tid] == before[tid] for tid in after if tid in before)
    assert after[waiting.native_id] == (os.SCHED_OTHER, 0)
    release.set()


@needs_fifo
def test_a_thread_may_raise_itself_alone():
    seen = {}

    def raised():
        seen["got"] = raise_threads(4, [threading.get_native_id()])
        seen["policy"] = _policy()

    before = _policies()
    thread = threading.Thread(target=raised)
    thread.start()
    thread.join()
    assert seen["got"].policy == "fifo" and seen["policy"] == (os.SCHED_FIFO, 4)
    assert _unchanged(before)  # every other thread (the raised one may still be ending)
    assert _policy() == (os.SCHED_OTHER, 0)  # the caller's own thread untouched


def test_a_refused_request_changes_nothing_and_says_why():
    before = _policies()
    got = raise_threads(100)  # above the kernel's maximum: refused on every machine
    assert got.policy == "normal" and got.threads == 0
    assert "SCHED_FIFO refused" in got.reason
    assert got.to_dict() == {"policy": "normal", "reason": got.reason}
    assert _unchanged(before)


def test_priority_zero_leaves_the_scheduler_alone():
    before = _policies()
    got = raise_threads(0)
    assert got.policy == "normal" and "0" in got.reason
    assert _unchanged(before)


def test_endpoints_take_two_below_the_hub_and_only_in_realtime():
    assert endpoint_priority("realtime", 10) == 8
    assert endpoint_priority("realtime", 2) == 1  # never below the lowest FIFO priority
    assert endpoint_priority("realtime", 0) == 0
    assert endpoint_priority("lockstep", 10) == 0


# --------------------------------------------------------------------------- CPU placement

needs_affinity = pytest.mark.skipif(
    not hasattr(os, "sched_setaffinity"), reason="no CPU affinity on this platform"
)


def _affinities() -> dict[int, set[int]]:
    out = {}
    for tid in map(int, os.listdir("/proc/self/task")):
        try:
            out[tid] = os.sched_getaffinity(tid)
        except ProcessLookupError:
            pass
    return out


def _kept(before: dict[int, set[int]]) -> bool:
    """Every thread of ``before`` still alive has the CPUs it had then (a thread an earlier
    test or the test runner started may end meanwhile)."""
    now = _affinities()
    return all(now[tid] == cpus for tid, cpus in before.items() if tid in now)


@needs_affinity
def test_placed_threads_and_those_they_start_stay_on_the_cpus_until_put_back():
    cpu = min(available_cpus())
    release = threading.Event()
    earlier = threading.Thread(target=release.wait, daemon=True)
    earlier.start()
    before = _affinities()
    got = place_threads("loop.cpus", [cpu])
    later = threading.Thread(target=release.wait, daemon=True)  # inherits the placement
    later.start()
    try:
        assert got.cpus == (cpu,) and not got.reason
        assert all(cpus == {cpu} for cpus in _affinities().values())
        assert os.sched_getaffinity(later.native_id) == {cpu}
    finally:
        restore_placement(got)
        release.set()
    assert _kept(before)
    earlier.join()
    later.join()


def test_no_cpus_asked_for_leaves_placement_to_the_os():
    before = _affinities()
    got = place_threads("loop.cpus", [])
    assert got.cpus == () and _kept(before)


@needs_affinity
def test_a_cpu_this_process_may_not_use_is_a_config_error_naming_the_key():
    missing = max(available_cpus()) + 1000
    before = _affinities()
    with pytest.raises(ConfigError, match=rf"body\.cpus: CPU {missing} is not available"):
        place_threads("body.cpus", [missing])
    with pytest.raises(ConfigError, match=r"loop\.cpus"):
        check_cpus("loop.cpus", [missing])
    assert _kept(before)


# ----------------------------------------------------------------- idle CPUs kept awake


def _fds_on(path: str) -> int:
    """How many of this process's file descriptors are open on ``path``."""
    fds = os.listdir("/proc/self/fd")
    return sum(1 for fd in fds if os.path.realpath(f"/proc/self/fd/{fd}") == path)


@pytest.mark.skipif(
    not os.access(PM_QOS_DEVICE, os.W_OK), reason=f"{PM_QOS_DEVICE} not writable here"
)
def test_cpus_kept_awake_ask_the_os_for_no_wake_up_latency_until_released():
    got = hold_cpus_awake()
    try:
        assert got.held and got.to_dict() == {"held": True, "latency_us": 0}
        # The device reads back the latency the system keeps now: the least of all requests.
        with open(PM_QOS_DEVICE, "rb") as device:
            assert struct.unpack("=i", device.read(4)) == (0,)
        assert _fds_on(PM_QOS_DEVICE) == 1
    finally:
        got.release()
    assert _fds_on(PM_QOS_DEVICE) == 0  # the request ends with its file
    got.release()  # twice is harmless


def test_the_request_is_a_zero_written_to_the_pm_qos_file(tmp_path):
    device = tmp_path / "cpu_dma_latency"
    device.touch()
    got = hold_cpus_awake(device=str(device))
    assert got.held
    got.release()
    assert struct.unpack("=i", device.read_bytes()) == (0,)


def test_without_pm_qos_or_access_to_it_nothing_is_held_and_the_reason_is_said(tmp_path):
    missing = hold_cpus_awake(device=str(tmp_path / "none"))
    assert not missing.held and "has no PM QoS" in missing.reason
    assert missing.to_dict() == {"held": False, "reason": missing.reason}
    refused = hold_cpus_awake(device=str(tmp_path))  # a folder: cannot be written
    assert not refused.held and str(tmp_path) in refused.reason
    not_asked = hold_cpus_awake(asked=False)
    assert not not_asked.held and "loop.keep_cpus_awake = false" in not_asked.reason
    for got in (missing, refused, not_asked):
        got.release()  # nothing to end
