"""CPU scheduling: real-time priority for realtime runs, and placement on chosen CPUs.

Under the kernel's ordinary scheduler a thread that wakes on time may still wait
a few milliseconds for a CPU that busy endpoints hold (seen here: a step start
2.5–4 ms late about once a minute on two cores). A ``SCHED_FIFO`` thread takes a
CPU the moment it wakes. The hub raises its own threads — the loop's and the
Zenoh threads that carry replies to it — for the steps of a realtime run only,
and puts them back afterwards. Endpoints started for a realtime run take two below
it (:func:`endpoint_priority`): a step's reply is then not held up by other work on
the machine, and the hub still takes a CPU first. The live burst analysis, a bus
observer of its own (``hub/burst_observer.py``), stays under the ordinary scheduler,
niced: it takes what CPU the loop leaves.

Needs ``CAP_SYS_NICE`` or an ``RLIMIT_RTPRIO`` of at least the priority asked
for; without either the run goes on under the ordinary scheduler and the
manifest says so. The kernel's real-time throttling (by default 5 % of each
second left to other work) still applies.

Placement (:func:`place_threads`, the ``cpus`` keys of the config) keeps a process's
threads on the CPUs named, for any mode; by default the OS places them.

Idle CPUs kept awake (:func:`hold_cpus_awake`, ``loop.keep_cpus_awake``): every step wakes a
thread on another CPU several times, and an idle CPU that has gone to sleep (a C-state on
bare metal; in a virtual machine, the virtual CPU halted and handed back to the host) takes
tens to hundreds of microseconds to wake. While a run steps, the hub and each endpoint ask
Linux's PM QoS (``/dev/cpu_dma_latency``, as ``cyclictest`` and tuned's
latency-performance profile do) for a wake-up latency of 0: idle CPUs then poll instead of
sleeping, at the cost of their power while the run lasts. The request ends when its file is
closed, by :meth:`CpusAwake.release` or by the process's death.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field

from hub.config import ConfigError


@dataclass
class Scheduling:
    """What a run got: the policy of the hub's threads while it stepped."""

    policy: str  # "fifo" or "normal"
    priority: int = 0
    threads: int = 0
    reason: str = ""  # why the policy is "normal"
    _previous: dict[int, tuple[int, int]] = field(default_factory=dict, repr=False)

    def include_new_threads(self) -> None:
        """Raise the threads started since :func:`raise_threads` (none inherit it). Call it
        once the loop has exchanged a step: zenoh-python starts a callback's thread on the
        callback's first call."""
        if self.policy == "fifo":
            try:
                _raise(self, [tid for tid in _thread_ids() if tid not in self._previous])
            except OSError:  # permitted a moment ago; if no longer, the run goes on
                pass

    def to_dict(self) -> dict:
        """The manifest's entry: the policy, with its priority and threads raised (``fifo``)
        or why (``normal``)."""
        out = {"policy": self.policy}
        if self.policy == "fifo":
            out.update(priority=self.priority, threads=self.threads)
        else:
            out["reason"] = self.reason
        return out


_FIFO = getattr(os, "SCHED_FIFO", 1) | getattr(os, "SCHED_RESET_ON_FORK", 0)


def endpoint_priority(mode: str, hub_priority: int) -> int:
    """The real-time priority an endpoint takes for a run (0: none) — two below the hub's
    (at least 1).

    Parameters
    ----------
    mode : str
        ``loop.mode``: only a realtime run raises its endpoints.
    hub_priority : int
        ``loop.realtime_priority`` (0: none).
    """
    if mode != "realtime" or hub_priority <= 0:
        return 0
    return max(hub_priority - 2, 1)


def _thread_ids() -> list[int]:
    return [int(t) for t in os.listdir("/proc/self/task")]


def raise_threads(priority: int, tids: Sequence[int] | None = None) -> Scheduling:
    """Put threads of this process under ``SCHED_FIFO``.

    Threads and processes started later do not inherit it (``SCHED_RESET_ON_FORK``):
    call this once the threads that matter (Zenoh's) exist.

    Parameters
    ----------
    priority : int
        The real-time priority (1-99); 0 or less leaves the scheduler alone.
    tids : sequence of int, optional
        The threads to raise (a thread raising itself passes
        ``[threading.get_native_id()]``); default: every thread of this process.

    Returns
    -------
    Scheduling
        What was done (``normal`` with the reason when refused: nothing is left raised),
        with what to undo in :func:`restore_threads`.
    """
    if priority <= 0:
        return Scheduling(
            "normal",
            reason="no real-time priority asked: a lockstep run, or loop.realtime_priority = 0",
        )
    if not hasattr(os, "sched_setscheduler"):
        return Scheduling("normal", reason="this platform has no SCHED_FIFO")
    got = Scheduling("fifo", priority)
    try:
        _raise(got, _thread_ids() if tids is None else list(tids))
    except OSError as exc:
        restore_threads(got)
        return Scheduling("normal", reason=f"SCHED_FIFO refused: {exc.strerror}")
    return got


def _raise(got: Scheduling, tids: list[int], priority: int | None = None) -> None:
    for tid in tids:
        try:
            previous = (os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority)
            os.sched_setscheduler(tid, _FIFO, os.sched_param(priority or got.priority))
        except ProcessLookupError:  # the thread ended meanwhile
            continue
        got._previous[tid] = previous
    got.threads = len(got._previous)


def restore_threads(got: Scheduling) -> None:
    """Undo :func:`raise_threads` for the threads it raised that still exist."""
    for tid, (policy, priority) in got._previous.items():
        try:
            os.sched_setscheduler(tid, policy, os.sched_param(priority))
        except OSError:  # ended, or no longer ours to change
            pass
    got._previous.clear()


def yield_cpu() -> str:
    """Put every thread of this process, and the threads they start from now on, under
    ``SCHED_IDLE``: they take a CPU only when no other process wants it, and give it up
    the moment one does.

    For a process that watches a run on the run's machine (the live dashboard): it then
    does not take a CPU from the loop, and when the CPUs are full it falls behind instead
    (it drops frames, not steps). Call it before the process starts the threads that work
    (Zenoh's, a server's): those started later inherit it. Returns ``"idle"``, or why the
    process stays under the ordinary scheduler.
    """
    if not hasattr(os, "SCHED_IDLE"):
        return "normal: this platform has no SCHED_IDLE"
    try:
        for tid in _thread_ids():  # numpy's BLAS may have started some at import
            try:
                os.sched_setscheduler(tid, os.SCHED_IDLE, os.sched_param(0))
            except ProcessLookupError:  # ended meanwhile
                continue
    except OSError as exc:
        return f"normal: SCHED_IDLE refused ({exc.strerror})"
    return "idle"


# --------------------------------------------------------------------------- CPU placement


def available_cpus() -> frozenset[int] | None:
    """The CPUs this process may run on (None where the platform cannot say)."""
    if not hasattr(os, "sched_getaffinity"):
        return None
    return frozenset(os.sched_getaffinity(0))


def check_cpus(key: str, cpus: Sequence[int]) -> None:
    """Check, before anything starts, that ``cpus`` are all CPUs this process may run on.

    Parameters
    ----------
    key : str
        The config key that asked for them (``loop.cpus``, ``<role>.cpus``).
    cpus : sequence of int
        The CPUs asked for (empty: nothing to check).

    Raises
    ------
    ConfigError
        A CPU this process may not run on; the message names ``key``.
    """
    available = available_cpus()
    if not cpus or available is None:
        return
    missing = sorted(set(cpus) - available)
    if missing:
        raise ConfigError(
            f"{key}: CPU {missing[0]} is not available to this process "
            f"(it may run on {sorted(available)})"
        )


@dataclass
class Placement:
    """Which CPUs this process's threads were kept on (empty: wherever the OS put them)."""

    cpus: tuple[int, ...] = ()
    reason: str = ""  # why a placement asked for was not made
    _previous: dict[int, frozenset[int]] = field(default_factory=dict, repr=False)


def place_threads(key: str, cpus: Sequence[int]) -> Placement:
    """Keep every thread of this process on ``cpus``, and the threads they start later,
    which inherit it: call this before Zenoh starts its threads. A platform without CPU
    affinity gets a placement with a reason; undo with :func:`restore_placement`.

    Why: the hub's threads hand each message to one another; kept on one CPU of their
    own, they neither wait behind the endpoints' threads nor wake a thread on another
    CPU (costly in a virtual machine). See docs/architecture.md, "CPU placement".

    Parameters
    ----------
    key : str
        The config key that asked for them (named by the error).
    cpus : sequence of int
        The CPUs to keep the threads on; empty leaves placement to the OS.

    Raises
    ------
    ConfigError
        A CPU this process may not run on.
    """
    if not cpus:
        return Placement()
    if not hasattr(os, "sched_setaffinity"):
        return Placement(reason="this platform cannot keep threads on chosen CPUs")
    check_cpus(key, cpus)
    got = Placement(tuple(sorted(set(cpus))))
    for tid in _thread_ids():
        try:
            previous = frozenset(os.sched_getaffinity(tid))
            os.sched_setaffinity(tid, got.cpus)
        except ProcessLookupError:  # the thread ended meanwhile
            continue
        got._previous[tid] = previous
    return got


def restore_placement(got: Placement) -> None:
    """Undo :func:`place_threads` for the threads it placed that still exist."""
    for tid, cpus in got._previous.items():
        try:
            os.sched_setaffinity(tid, cpus)
        except OSError:  # ended, or no longer ours to change
            pass
    got._previous.clear()


# --------------------------------------------------------------------------- idle CPUs awake

PM_QOS_DEVICE = "/dev/cpu_dma_latency"


@dataclass
class CpusAwake:
    """What a run got: whether idle CPUs were kept from sleeping while it stepped."""

    held: bool
    reason: str = ""  # why not
    _fd: int | None = field(default=None, repr=False)

    def release(self) -> None:
        """End the request (idle CPUs may sleep again); harmless if none is held."""
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)

    def to_dict(self) -> dict:
        """The manifest's entry: held (at a latency of 0 µs), or not and why."""
        return (
            {"held": True, "latency_us": 0} if self.held else {"held": False, "reason": self.reason}
        )


def hold_cpus_awake(asked: bool = True, device: str = PM_QOS_DEVICE) -> CpusAwake:
    """Ask the OS to keep every idle CPU awake (a wake-up latency of 0 µs) until
    :meth:`CpusAwake.release`, or until this process ends.

    Needs write access to ``device`` (root, or a udev rule: docs/architecture.md); without
    it, or on a system without PM QoS, nothing changes and the result says why.

    Parameters
    ----------
    asked : bool
        ``loop.keep_cpus_awake``; False asks nothing (the result says so).
    device : str
        The PM QoS device file written to.
    """
    if not asked:
        return CpusAwake(False, reason="not asked (loop.keep_cpus_awake = false)")
    try:
        fd = os.open(device, os.O_WRONLY | os.O_CLOEXEC)
    except FileNotFoundError:
        return CpusAwake(False, reason=f"no {device}: this system has no PM QoS")
    except OSError as exc:
        return CpusAwake(False, reason=f"{device}: {exc.strerror}")
    try:
        os.write(fd, struct.pack("=i", 0))
    except OSError as exc:
        os.close(fd)
        return CpusAwake(False, reason=f"{device} refused the request: {exc.strerror}")
    return CpusAwake(True, _fd=fd)
