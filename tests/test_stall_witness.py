"""The stall witness that realtime tests use to tell a stall of the host from their own."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

from hub.record import Frame, RunRecord
from tests.harness import needs_fifo
from tests.stall_witness import StallWitness

MS = 1_000_000  # ns


@needs_fifo
def test_a_witness_held_off_its_cpu_reports_a_stall_of_that_length():
    with StallWitness() as witness:
        cpu, pid = next(iter(witness.pids.items()))
        stopped_ns = time.time_ns()
        os.kill(pid, signal.SIGSTOP)  # as a hypervisor holding its CPU would
        time.sleep(0.03)
        resumed_ns = time.time_ns()
        os.kill(pid, signal.SIGCONT)
        time.sleep(0.02)
    # (the host may stall a CPU meanwhile too: only the one held this long is ours)
    held = [(start, end) for start, end, c in witness.stalls if c == cpu and end - start >= 30 * MS]
    ((start, end),) = held
    # it was asleep when it was stopped (or had just woken: a signal lands a little later)
    assert stopped_ns - 5 * MS <= start <= stopped_ns + MS
    assert resumed_ns <= end < resumed_ns + 100 * MS


def record_with_missed(steps: list[int], period_ms: float = 10.0) -> RunRecord:
    """A run's record whose culture reply of each step in ``steps`` was found missing at
    the step's deadline (1.8 periods after it began); the first step began at 1 s."""
    t0 = 1_000 * MS
    frames = [Frame(t0, "tx", "nv/test/culture/stim", b"")]
    for step in steps:
        at = t0 + int((step + 1.8) * period_ms * MS)
        frames.append(Frame(at, "ev", "missed", {"role": "culture", "step": step}))
    return RunRecord(Path("."), {"timing": {"period_ms": period_ms}}, frames)


def test_a_missed_step_is_excused_by_a_stall_between_its_window_and_its_deadline():
    witness = StallWitness()
    record = record_with_missed([10, 50])
    # step 10 began at 1.100 s, its window at 1.090 s; it was found missing at 1.118 s
    witness.stalls = [(1_095 * MS, 1_101 * MS, 0)]
    assert witness.unexcused(record) == {"culture": [50]}
    witness.stalls = [(1_119 * MS, 1_130 * MS, 1)]  # after the deadline: no excuse
    assert witness.unexcused(record) == {"culture": [10, 50]}
    witness.stalls = [(1_080 * MS, 1_089 * MS, 1)]  # before its window: no excuse
    assert witness.unexcused(record) == {"culture": [10, 50]}
    assert not witness.explains_every_miss(record)
    witness.stalls = [(1_095 * MS, 1_101 * MS, 0), (1_500 * MS, 1_510 * MS, 1)]
    assert witness.explains_every_miss(record)
    witness.stalls = []  # no stall: nothing to explain a miss with
    assert not witness.explains_every_miss(record_with_missed([]))


def test_a_benchmark_reports_the_stalls_and_the_missed_replies_no_stall_explains():
    witness = StallWitness()
    witness.stalls = [(1_095 * MS, 1_101 * MS, 0), (2_000 * MS, 2_004 * MS, 1)]
    figures = witness.figures(record_with_missed([10, 50]))
    assert figures["missed_replies"] == 2 and figures["missed_replies_unexplained"] == 1
    if witness.active:
        assert figures["host_stalls"] == 2 and figures["host_stall_max_ms"] == 6.0
