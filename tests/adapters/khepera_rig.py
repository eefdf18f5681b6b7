"""A Khepera emulator on a real pseudo-terminal and the adapter's parts opened on it."""

from __future__ import annotations

from adapters.khepera.calibration import IRCalibration, Odometry
from adapters.khepera.driver import KheperaDriver
from adapters.khepera.emulator import KheperaEmulator
from adapters.khepera.endpoint import KHEPERA2_UNITS, KheperaEndpoint
from adapters.khepera.link import SerialLink, open_port
from devices import khepera


def open_link(emulator: KheperaEmulator, *, baud=9600, timeout_s=0.25, silent_s=1.0):
    port = open_port(emulator.path, baud=baud, timeout_s=timeout_s)
    return SerialLink(port, timeout_s=timeout_s, silent_s=silent_s)


def make_driver(emulator: KheperaEmulator, *, watchdog_s=0.5, **link) -> KheperaDriver:
    return KheperaDriver(
        open_link(emulator, **link),
        units=KHEPERA2_UNITS,
        calibration=IRCalibration.published(),
        odometry=Odometry(khepera.KHEPERA2_PULSE_M, khepera.KHEPERA2_WHEEL_BASE_M),
        watchdog_s=watchdog_s,
    )


def make_endpoint(emulator: KheperaEmulator, **driver) -> KheperaEndpoint:
    return KheperaEndpoint(make_driver(emulator, **driver), start_pose=emulator.arena.pose)


def motor_commands(emulator: KheperaEmulator) -> list[tuple[float, bytes]]:
    """The ``D`` commands the emulator received, with their times."""
    return [(t, line) for t, line in list(emulator.commands) if line.startswith(b"D")]
