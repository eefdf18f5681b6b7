"""The adapter against the emulator through a real pseudo-terminal: replies, units, faults."""

from __future__ import annotations

import contextlib
import math
import time

import numpy as np
import pytest

from adapters.khepera.emulator import KheperaEmulator
from adapters.khepera.link import LinkFault
from adapters.khepera.protocol import ReplyError
from devices import khepera
from tests.adapters.khepera_rig import (
    check_odometry_follows_an_arc,
    make_driver,
    motor_commands,
    open_link,
)
from tests.harness import wait_for


@pytest.fixture
def emulator():
    with KheperaEmulator() as emu:
        yield emu


def test_every_command_of_the_protocol_gets_its_reply_parsed(emulator):
    link = open_link(emulator)
    assert link.transact("B").fields[0].startswith("nv-emulator")
    assert link.transact("D", 5, -5).fields == ()
    assert link.transact("E").fields == (5, -5)
    assert link.transact("G", 100, 200).fields == ()
    left, right = link.transact("H").fields
    assert left >= 100 and right <= 200  # counting on from where they were set
    assert len(link.transact("N").fields) == 8
    assert len(link.transact("O").fields) == 8
    assert link.transact("L", 0, 1).fields == () and emulator.leds[0] == 1
    with pytest.raises(ReplyError, match="refused"):
        link.transact("Z")
    assert link.counts["refused"] == link.tries
    link.transact("D", 0, 0)


def test_a_straight_run_of_known_speed_and_time_covers_the_expected_distance(emulator):
    link = open_link(emulator)
    link.transact("G", 0, 0)
    link.transact("D", 10, 10)  # 10 units = 0.08 m/s
    t0 = time.monotonic()
    while time.monotonic() - t0 < 1.0:
        link.transact("N")  # the loop's traffic meanwhile
    link.transact("D", 0, 0)
    elapsed_s = time.monotonic() - t0
    left, right = link.transact("H").fields
    expected_m = 10 * khepera.KHEPERA2_SPEED_UNIT_MPS * elapsed_s
    for pulses in (left, right):
        assert pulses * khepera.KHEPERA2_PULSE_M == pytest.approx(expected_m, rel=0.05)


def test_odometry_of_the_driver_follows_the_emulated_robot(emulator):
    check_odometry_follows_an_arc(emulator)


def test_ir_values_become_the_true_distance_through_the_calibration(emulator):
    # The robot 30 mm (front sensors) from the arena's wall, facing it.
    emulator.arena.reset((0.0, -0.5 + 0.025 + 0.03, -math.pi / 2))
    driver = make_driver(emulator)
    driver.connect()
    try:
        true_m = emulator.arena.read_sensors()
        ranges = driver.latest().ranges_m
        seen = true_m < 0.1
        assert seen[[2, 3]].all()  # the two front sensors
        np.testing.assert_allclose(ranges[seen], true_m[seen], atol=0.001)
        np.testing.assert_allclose(ranges[~seen], 0.1, rtol=1e-6)  # beyond the table: nothing seen
    finally:
        driver.close()


@pytest.mark.parametrize("fault, counted", [("garbage_next", "garbled"), ("drop_next", "timeout"),
                                            ("late_next", "order")])  # fmt: skip
def test_a_bad_reply_is_counted_and_the_link_resynchronised(emulator, fault, counted):
    link = open_link(emulator, timeout_s=0.1)
    link.transact("N")
    setattr(emulator.faults, fault, 1)
    assert len(link.transact("N").fields) == 8  # the next attempt, or the reply after
    assert link.counts[counted] == 1
    assert len(link.transact("H").fields) == 2  # and the link goes on in step


def test_the_driver_rides_out_faults_and_keeps_reading(emulator):
    driver = make_driver(emulator, timeout_s=0.1)
    driver.connect()
    try:
        emulator.faults.garbage_next = 3
        emulator.faults.drop_next = 2
        wait_for(lambda: emulator.faults.fired["drop"] == 2, 5.0)
        before = driver.latest().t_mono_s
        wait_for(lambda: driver.latest().t_mono_s > before, 2.0)
        counts = driver.stats()
        assert counts["garbled"] == 3 and counts["timeout"] == 2
        assert driver.fault is None
    finally:
        driver.close()


def test_a_silent_link_is_a_fault_named_as_such(emulator):
    faults = []
    driver = make_driver(emulator, timeout_s=0.1, silent_s=0.5)
    driver.on_fault = faults.append
    driver.connect()
    emulator.faults.stall_until = time.monotonic() + 60
    wait_for(lambda: faults, 5.0)
    assert isinstance(faults[0], LinkFault) and "silent" in str(faults[0])
    driver.close()


def test_the_watchdog_stops_the_motors_when_commands_stop(emulator):
    driver = make_driver(emulator, watchdog_s=0.3)
    driver.connect()
    try:
        commanded = time.monotonic()
        driver.command(0.1, 0.1)
        wait_for(lambda: emulator.speed_units == (12, 12), 2.0)
        wait_for(lambda: emulator.speed_units == (0, 0), 2.0)
        t_stop, line = motor_commands(emulator)[-1]
        assert line == b"D,0,0"
        assert 0.3 <= t_stop - commanded <= 0.3 + 2 * driver.cycle_ms / 1e3 + 0.05
        assert driver.counts["watchdog_stops"] == 1
    finally:
        driver.close()


def test_the_byte_time_of_the_chosen_baud_is_emulated():
    with KheperaEmulator(baud=9600) as slow:
        link = open_link(slow)
        t0 = time.perf_counter()
        link.transact("N")
        elapsed_s = time.perf_counter() - t0
    # "N\r" and "n,0,...,0\r\n" (19 bytes) at 11 bits per byte
    assert elapsed_s >= 21 * 11 / 9600


def test_the_stop_guard_stops_the_motors_only_when_its_adapter_is_gone(emulator):
    """Released by ``close`` (the adapter stopped the motors itself) the guard writes
    nothing; with its pipe at an end unreleased (the adapter's process gone) it sends the
    stop — after a line end, so that a command the adapter was cut off in does not swallow
    it — and ends."""
    released = open_link(emulator)
    released.guard_motors()
    released.transact("D", 3, 3)
    guard = released.guard.process
    released.close()
    assert guard.wait(timeout=5) == 0
    assert emulator.speed_units == (3, 3)  # nothing written by the guard

    dying = open_link(emulator)
    dying.guard_motors()
    dying.transact("D", 4, 4)
    dying.port.write(b"D,5")  # cut off mid-command
    dying.guard.abandon()  # as the process's end closes it: no release
    assert dying.guard.process.wait(timeout=5) == 0
    wait_for(lambda: emulator.speed_units == (0, 0), 2.0)
    assert motor_commands(emulator)[-1][1] == b"D,0,0"
    dying.close()


@contextlib.contextmanager
def guarded_link(emulator, freeze_s: float):
    """A link with a stop guard watching for beats; closed as an adapter does (motors
    stopped, guard released), and the guard found ended cleanly."""
    link = open_link(emulator)
    link.guard_motors(freeze_s=freeze_s)
    try:
        yield link
    finally:
        guard = link.guard.process
        link.transact("D", 0, 0)
        link.close()
    assert guard.wait(timeout=5) == 0


def test_the_stop_guard_stops_the_motors_when_the_adapter_stops_beating(emulator, capfd):
    """With ``freeze_s`` the guard also stops the robot when the adapter's beats stop for
    that long (its process frozen, or its serial thread hung) — and only once armed by a
    first beat. The adapter learns it at its next beat (so it sends its speeds again), and
    the guard watches on: a stall is survived."""
    with guarded_link(emulator, freeze_s=0.3) as link:
        link.transact("D", 4, 4)
        time.sleep(0.5)  # not armed yet: no beat came
        assert emulator.speed_units == (4, 4)
        for _ in range(8):  # beating: the guard stays quiet
            time.sleep(0.1)
            assert link.beat() is False
        stood = time.monotonic()  # no more beats from here: as a frozen process
        assert emulator.speed_units == (4, 4)
        wait_for(lambda: emulator.speed_units == (0, 0), 2.0)
        t_stop, line = motor_commands(emulator)[-1]
        assert line == b"D,0,0" and 0.3 <= t_stop - stood <= 0.3 + 0.2
        assert link.beat() is True  # told once, at the first beat after
        assert link.beat() is False
        link.transact("D", 5, 5)  # the adapter drives again; the guard watches on
        for _ in range(5):
            link.beat()
            time.sleep(0.1)
        assert emulator.speed_units == (5, 5)
    err = capfd.readouterr().err
    assert "gave no sign of life for 0.3 s" in err and "alive again" in err


def test_beats_that_stop_on_purpose_are_no_freeze(emulator, capfd):
    """The serial thread ends (its link failed, or the adapter closes): its beats stop, and
    the guard, told so, stands by for the adapter's end only — no stop, no "frozen"."""
    with guarded_link(emulator, freeze_s=0.3) as link:
        link.transact("D", 4, 4)
        link.beat()
        link.rest()
        time.sleep(0.8)
        assert emulator.speed_units == (4, 4)
    assert "stop guard" not in capfd.readouterr().err


def test_a_stop_is_not_undone_by_a_speed_the_serial_thread_was_about_to_send(emulator):
    """``stop_motors`` while the serial thread had read a speed and not yet sent it: the stop
    went first and the speed after it, so the robot drove again after the stop had
    returned (until the next cycle). The speed under way now goes first, then the stop."""
    import threading

    driver = make_driver(emulator, watchdog_s=5.0)
    driver.connect()
    about_to_send, go = threading.Event(), threading.Event()
    transact = driver.link.transact

    def held(letter, *values):  # the serial thread's speed write, held at the link's door
        if letter == "D" and values != (0, 0) and threading.current_thread() is driver._thread:
            about_to_send.set()
            go.wait(5.0)
        return transact(letter, *values)

    driver.link.transact = held
    try:
        n = len(motor_commands(emulator))
        driver.command(0.1, 0.1)
        assert about_to_send.wait(5.0)
        stopper = threading.Thread(target=driver.stop_motors)
        stopper.start()
        stopper.join(0.5)  # done here only if the stop overtook the speed under way
        go.set()
        stopper.join(5.0)
        cycles = len(driver.cycles_s)
        wait_for(lambda: len(driver.cycles_s) >= cycles + 2, 5.0)  # two cycles since
        sent = [line for _, line in motor_commands(emulator)[n:]]
        # 0.1 m/s: 12 units of 8 mm/s; then the stop, and nothing but stops. The serial
        # thread's next cycle may take the motor lock before the stopper does and send the
        # new target (0, 0) itself: the stop then goes twice, never a speed after it.
        assert sent[0] == b"D,12,12" and sent[1] == b"D,0,0", sent
        assert set(sent[1:]) == {b"D,0,0"} and len(sent) <= 3, sent
        assert emulator.speed_units == (0, 0)
    finally:
        go.set()
        driver.close()


def test_a_stop_after_the_link_closed_is_no_error_the_close_stopped_the_motors(emulator):
    """The hub's going (a bus thread makes the robot safe) and the endpoint's end (it closes
    the driver) may come in either order. Closed first, the close stopped the motors, and a
    stop after it does nothing (it raised pyserial's TypeError from the bus thread)."""
    driver = make_driver(emulator, watchdog_s=5.0)
    driver.connect()
    driver.command(0.1, 0.1)
    wait_for(lambda: emulator.speed_units != (0, 0), 5.0)
    driver.close()
    assert emulator.speed_units == (0, 0)
    driver.stop_motors()
    with pytest.raises(LinkFault, match="closed"):
        driver.link.transact("D", 0, 0)


def test_an_emulators_link_taken_over_by_another_is_left_to_it_at_exit(tmp_path):
    """Two emulators started on one --link name: the second takes it, and the first's exit
    leaves the link to the second (an experiment file naming the link still reaches a robot)."""
    import os
    import subprocess
    import sys

    from hub.launch import die_with_parent

    link = tmp_path / "khepera"

    def start():
        proc = subprocess.Popen(
            [sys.executable, "-m", "hub.cli", "emulate", "khepera", "--link", str(link)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            preexec_fn=die_with_parent,
        )  # fmt: skip
        return proc, proc.stdout.readline().strip()

    first, first_path = start()
    second, second_path = start()
    try:
        assert os.readlink(link) == second_path != first_path
        first.terminate()
        assert first.wait(timeout=10) == 0
        assert f"which is there; it now links to this emulator ({second_path})" in (
            second.stderr.readline() + second.stderr.readline()
        )
        assert os.readlink(link) == second_path
    finally:
        for proc in (first, second):
            proc.terminate()
            proc.wait(timeout=10)
    assert not link.is_symlink()  # the second's own link, removed at its exit
