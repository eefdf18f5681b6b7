"""A Khepera emulator on a real pseudo-terminal and the adapter's parts opened on it."""

from __future__ import annotations

from adapters.khepera.calibration import IRCalibration, Odometry
from adapters.khepera.driver import KheperaDriver, WheelUnits
from adapters.khepera.emulator import KheperaEmulator
from adapters.khepera.endpoint import KheperaEndpoint
from adapters.khepera.link import SerialLink, open_port


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
