"""A Khepera emulator on a real pseudo-terminal and the adapter's parts opened on it."""

from __future__ import annotations

import gc
import math
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from adapters.khepera.calibration import IRCalibration, Odometry
from adapters.khepera.driver import KheperaDriver, WheelUnits
from adapters.khepera.emulator import KheperaEmulator
from adapters.khepera.endpoint import KheperaEndpoint
from adapters.khepera.link import SerialLink, open_port
from hub.launch import die_with_parent
from tests.harness import wait_for


@contextmanager
def frozen_heap() -> Iterator[None]:
    """The test session's objects left out of garbage collections meanwhile (a full one of
    them takes ~120 ms): for a realtime run against an emulator on a thread of this
    process, whose replies a collection would hold up."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


@contextmanager
def emulator_process(baud: int) -> Iterator[str]:
    """``neuvision emulate khepera --baud BAUD`` in a process of its own, as a robot is a
    device of its own; yields its device path.

    For realtime runs: an emulator on a thread of the test's process would share its
    interpreter, and a full garbage collection of the test session's objects (~230,000
    after collection, ~120 ms) would hold its replies (a CI run's readings 131 ms old). The
    emulator's process freezes its own heap before it serves, for the same reason."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "hub.cli", "emulate", "khepera", "--baud", str(baud)],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        preexec_fn=die_with_parent,
    )  # fmt: skip
    try:
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/"), f"the emulator printed {path!r}"
        yield path
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def open_link(emulator: KheperaEmulator, *, baud=9600, timeout_s=0.25, silent_s=1.0):
    port = open_port(emulator.path, baud=baud, timeout_s=timeout_s)
    return SerialLink(port, timeout_s=timeout_s, silent_s=silent_s, dialect=emulator.dialect)


def make_driver(emulator: KheperaEmulator, *, watchdog_s=0.5, **link) -> KheperaDriver:
    """The adapter's driver for the emulated model (its IR table: the emulator's own, or
    the published Khepera II one)."""
    model = emulator.model
    table = emulator.ir_table
    return KheperaDriver(
        open_link(emulator, **link),
        units=WheelUnits.of(model),
        calibration=IRCalibration.published() if table is None else IRCalibration(table),
        odometry=Odometry(model.pulse_m, model.wheel_base_m),
        watchdog_s=watchdog_s,
    )


def make_endpoint(emulator: KheperaEmulator, **driver) -> KheperaEndpoint:
    return KheperaEndpoint(make_driver(emulator, **driver), start_pose=emulator.arena.pose)


def motor_commands(emulator: KheperaEmulator) -> list[tuple[float, bytes]]:
    """The ``D`` commands the emulator received, with their times."""
    return [(t, line) for t, line in list(emulator.commands) if line.startswith(b"D")]


def check_odometry_follows_an_arc(emulator: KheperaEmulator, **link) -> None:
    """Drive the emulated robot along an arc through the adapter's driver; its odometry
    ends within 5 % of the distance travelled from the true pose, and 0.05 rad of heading."""
    driver = make_driver(emulator, watchdog_s=5.0, **link)
    driver.connect()
    driver.reset(emulator.arena.pose)
    try:
        start = np.array(emulator.arena.pose)
        driver.command(0.06, 0.1)
        time.sleep(1.5)  # let it drive; what is compared is where it went
        driver.command(0.0, 0.0)
        wait_for(lambda: emulator.speed_units == (0, 0), 2.0)
        first = driver.latest().t_mono_s
        wait_for(lambda: driver.latest().t_mono_s > first + 0.05, 2.0)
        true, odo = np.array(emulator.arena.pose), driver.latest().pose
        travelled_m = np.hypot(*(true[:2] - start[:2]))
        assert travelled_m > 0.08
        assert np.hypot(*(odo[:2] - true[:2])) < 0.05 * travelled_m
        assert abs(math.remainder(odo[2] - true[2], 2 * math.pi)) < 0.05
    finally:
        driver.close()
