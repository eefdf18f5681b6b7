"""What the host did while a benchmark measured, and children that never outlive it.

These machines are virtual and shared: a realtime figure swings with the CPU time the
hypervisor gives to other guests (*steal*, the ``steal`` column of ``/proc/stat``).
:class:`StealMeter` reads it around a measurement so that each realtime figure is
printed with the steal share it was taken under.

A benchmark killed by a timeout must leave no process behind: :func:`child_popen`
starts children that the kernel ends when the benchmark dies (``PR_SET_PDEATHSIG``,
even on SIGKILL), and :func:`end_children_on_signal` turns SIGTERM/SIGINT into a clean
exit that stops them first.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from dataclasses import dataclass

from hub.launch import die_with_parent

_children: list[subprocess.Popen] = []


def cpu_times() -> tuple[int, int]:
    """(steal, total) jiffies of all CPUs since boot, from ``/proc/stat``; (0, 0) if unknown."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
    except OSError:
        return 0, 0
    # cpu user nice system idle iowait irq softirq steal guest guest_nice
    values = [int(v) for v in fields[1:9]]
    return (values[7] if len(values) > 7 else 0), sum(values)


@dataclass
class StealMeter:
    """Steal share of all CPUs between :meth:`start` and :meth:`stop` (0.0-1.0)."""

    steal0: int = 0
    total0: int = 0
    share: float = float("nan")

    def start(self) -> StealMeter:
        self.steal0, self.total0 = cpu_times()
        return self

    def stop(self) -> float:
        steal, total = cpu_times()
        d_total = total - self.total0
        self.share = (steal - self.steal0) / d_total if d_total > 0 else float("nan")
        return self.share

    def __enter__(self) -> StealMeter:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def child_popen(cmd: list[str], **kwargs) -> subprocess.Popen:
    """``subprocess.Popen`` of a child that is sent SIGTERM if this process dies."""
    popen = subprocess.Popen(cmd, preexec_fn=die_with_parent, **kwargs)
    _children.append(popen)
    return popen


def child_run(cmd: list[str], **kwargs) -> subprocess.CompletedProcess:
    """``subprocess.run`` (output captured as text) of a child that dies with this process."""
    with child_popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kwargs) as p:
        out, err = p.communicate()
    _children.remove(p)
    return subprocess.CompletedProcess(cmd, p.returncode, out, err)


def end_children_on_signal() -> None:
    """On SIGTERM or SIGINT: stop the children started here, then exit with 128 + signal."""

    def handler(signum, _frame):
        for p in _children:
            if p.poll() is None:
                p.terminate()
        for p in _children:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
        sys.stderr.write(f"benchmark ended by signal {signum}; children stopped\n")
        os._exit(128 + signum)

    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, handler)


def interrupt_on_sigterm() -> None:
    """SIGTERM raises KeyboardInterrupt in the main thread, as Ctrl-C does: a benchmark
    that runs the hub in-process then closes up through its ``finally`` clauses (local
    endpoints stopped) before it exits."""

    def handler(signum, _frame):
        raise KeyboardInterrupt(f"signal {signum}")

    signal.signal(signal.SIGTERM, handler)
