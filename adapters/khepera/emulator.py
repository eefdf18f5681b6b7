"""An emulator of a Khepera II or III on a pseudo-terminal: the real protocol, a simulated
robot.

:class:`KheperaEmulator` opens a pseudo-terminal and answers the Khepera's serial protocol
on it (a Khepera II: ``B D E G H N O L``; a Khepera III: ``B D E I R N O`` with its type
prefixes and time stamps; an unknown command gets ``Command not found``) from a robot
driven in real time through a :mod:`sim_robot` world: wheel speeds in the robot's units,
position counters in encoder pulses, proximity values from the IR response model (a Khepera
III: from a lab's table, as none is published). Anything that opens the device path with
pyserial sees a Khepera. It is an **emulator**: the ambient light (``O``) and a Khepera III's
ground sensors are constants, the IR values carry no noise floor, and the firmware's own
processing time is not modelled; with ``baud`` set, each exchange takes the time its bytes
take on a wire at that baud.

Faults can be injected for tests (:class:`Faults`): garbage bytes before a reply, a reply
dropped, a stall. ``neuvision emulate khepera`` runs one from the command line.
"""

from __future__ import annotations

import gc
import logging
import math
import os
import select
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from adapters.khepera.link import byte_time_s
from adapters.khepera.protocol import (
    COUNTER_COMMANDS,
    UNKNOWN_COMMAND_REPLY,
    parse_command,
    reply_line,
)
from devices import khepera
from hub.stopping import StopFlag
from sim_robot import Arena
from sim_robot.ir import table_value
from sim_robot.world import load_world

log = logging.getLogger(__name__)

#: the emulated robot's world unless another is given: the paper's arena with the robot in it
DEFAULT_EMULATOR_WORLDS = {
    dialect: Path(__file__).resolve().parents[2] / "configs" / "worlds" / f"{dialect}.toml"
    for dialect in khepera.MODELS
}
#: what ``B`` answers: the emulator names itself instead of a BIOS version
VERSION_FIELDS = ("nv-emulator-1", "6")
#: what ``O`` answers for each sensor (no light model: a dim, uniform room)
AMBIENT_VALUE = 450
#: what a Khepera III's two ground sensors read (no floor model: a uniform floor)
GROUND_VALUE = 600
#: the physics advances by at most this much per substep (s)
MAX_SUBSTEP_S = 0.01


@dataclass
class Faults:
    """Faults to inject (tests; ``neuvision emulate khepera --garbage-every ...``).

    One-shot counts are used up as they fire; ``*_every`` fire on every n-th reply.
    """

    garbage_next: int = 0  # replies preceded by garbage bytes
    drop_next: int = 0  # replies not sent at all
    late_next: int = 0  # replies preceded by a late ``d`` reply (out of order)
    garbage_every: int = 0
    drop_every: int = 0
    stall_until: float = 0.0  # time.monotonic() before which nothing is answered
    fired: dict = field(default_factory=lambda: {"garbage": 0, "drop": 0, "late": 0, "stall": 0})


class KheperaEmulator:
    """A Khepera answering on a pseudo-terminal, moving in a simulated world.

    Parameters
    ----------
    world : str or Path, optional
        A world file with the robot to emulate (default: the model's, in the paper's arena).
    dialect : str
        The robot's model: ``khepera2`` or ``khepera3``.
    ir_table : array of (distance_m, value), optional
        The IR response (required for a Khepera III; a Khepera II's is the world's model).
    baud : int or None
        Emulated line speed: each exchange takes its bytes' time at this baud (None:
        as fast as the pseudo-terminal goes).
    stop_bits : int, optional
        For the byte time (a start bit, 8 data bits and these; default the model's).
    seed : int
        Range-finder noise of the world, if it has any.

    Attributes
    ----------
    path : str
        The device path to open (``/dev/pts/N``).
    commands : list of (float, bytes)
        Every command line received, with its ``time.monotonic()``.
    """

    def __init__(
        self,
        world: str | Path | None = None,
        *,
        dialect: str = "khepera2",
        ir_table=None,
        baud: int | None = None,
        stop_bits: int | None = None,
        seed: int = 0,
    ):
        if dialect not in khepera.MODELS:
            raise ValueError(f"dialect must be one of {sorted(khepera.MODELS)}, got {dialect!r}")
        self.model = khepera.MODELS[dialect]
        if self.model.ir_table is None and ir_table is None:
            raise ValueError(f"a {self.model.name} has no published IR response: give ir_table")
        self.ir_table = None if ir_table is None else np.asarray(ir_table, dtype=np.float64)
        self.arena = Arena(load_world(world or DEFAULT_EMULATOR_WORLDS[dialect]), seed=seed)
        # The arena's kernels compile on first use (seconds, without numba's cache): done
        # here, a robot's first replies would come late and the adapter take it for silent.
        self.arena.step(0.0, 0.0, 0.01)
        self.arena.read_ir()
        self.arena.reset()
        stop_bits = self.model.stop_bits if stop_bits is None else stop_bits
        self.byte_s = byte_time_s(baud, stop_bits) if baud else 0.0
        self.faults = Faults()
        self.commands: list[tuple[float, bytes]] = []
        self.replies = 0
        self.speed_units = (0, 0)
        self.counters_pulses = np.zeros(2)
        self.leds = [0, 0]
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no line discipline: bytes pass as they are
        self.path = os.ttyname(self._slave)
        self._last_t = self._started = time.monotonic()
        self._stop = StopFlag()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    # ------------------------------------------------------------ running

    def start(self) -> KheperaEmulator:
        """Answer on a thread of its own; returns self."""
        self._thread = threading.Thread(target=self.serve, name="khepera-emulator", daemon=True)
        self._thread.start()
        return self

    def serve(self) -> None:
        """Answer commands until :meth:`stop`."""
        buffer = b""
        while not self._stop.is_set():
            ready, _, _ = select.select([self._master], [], [], 0.05)
            if not ready:
                continue
            try:
                chunk = os.read(self._master, 4096)
            except OSError:  # the pseudo-terminal went away
                return
            buffer += chunk
            while True:
                end = min(
                    (i for i in (buffer.find(b"\r"), buffer.find(b"\n")) if i >= 0), default=-1
                )
                if end < 0:
                    break
                line, buffer = buffer[:end], buffer[end + 1 :]
                if line:
                    self._answer(line)

    def stop(self) -> None:
        """Stop answering and close the pseudo-terminal."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> KheperaEmulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # ------------------------------------------------------------ the robot

    @property
    def dialect(self) -> str:
        """The emulated robot's serial dialect: ``khepera2`` or ``khepera3``."""
        return self.model.dialect

    @property
    def wheel_mps(self) -> tuple[float, float]:
        """The left and right wheel speeds last commanded (``D``), in m/s."""
        unit = self.model.speed_unit_mps
        return (self.speed_units[0] * unit, self.speed_units[1] * unit)

    def advance(self, now: float | None = None) -> None:
        """Move the robot over the time passed since the last call, at its wheel speeds."""
        with self._lock:
            now = time.monotonic() if now is None else now
            left = now - self._last_t
            self._last_t = now
            left_mps, right_mps = self.wheel_mps
            self.counters_pulses += np.array([left_mps, right_mps]) * left / self.model.pulse_m
            while left > 1e-9:
                dt = min(left, MAX_SUBSTEP_S)
                self.arena.step(left_mps, right_mps, dt)
                left -= dt

    def _answer(self, line: bytes) -> None:
        received = time.monotonic()
        self.commands.append((received, line))
        self.advance(received)
        try:
            letter, args = parse_command(line)
            reply = self._reply(letter, args)
        except (ValueError, UnicodeDecodeError):
            reply = UNKNOWN_COMMAND_REPLY
        faults = self.faults
        if received < faults.stall_until:
            faults.fired["stall"] += 1
            return
        self.replies += 1
        if faults.drop_next or (faults.drop_every and self.replies % faults.drop_every == 0):
            faults.drop_next = max(0, faults.drop_next - 1)
            faults.fired["drop"] += 1
            return
        if faults.garbage_next or (
            faults.garbage_every and self.replies % faults.garbage_every == 0
        ):
            faults.garbage_next = max(0, faults.garbage_next - 1)
            faults.fired["garbage"] += 1
            reply = b"\x8f#\xfe" + reply
        if faults.late_next:
            faults.late_next -= 1
            faults.fired["late"] += 1
            reply = reply_line("d") + reply
        if self.byte_s:
            # the command's bytes and the reply's, as a wire at this baud would take them
            lag_s = (len(line) + 1 + len(reply)) * self.byte_s - (time.monotonic() - received)
            if lag_s > 0:
                time.sleep(lag_s)
        try:
            os.write(self._master, reply)
        except OSError:
            pass

    def _reply(self, letter: str, args: tuple[int, ...]) -> bytes:
        limit = self.model.max_speed_units
        k3 = self.dialect == "khepera3"
        set_counters, read_counters = COUNTER_COMMANDS[self.dialect]
        if letter == "B":
            return reply_line("b", *VERSION_FIELDS)
        if letter == "D" and len(args) == 2:
            self.speed_units = tuple(int(np.clip(a, -limit, limit)) for a in args)
            return reply_line("d")
        if letter == "E":
            return reply_line("e", *self.speed_units)
        if letter == set_counters and len(args) == 2:
            self.counters_pulses[:] = args
            return reply_line(set_counters)
        if letter == read_counters:
            return reply_line(read_counters, *(int(v) for v in np.trunc(self.counters_pulses)))
        if letter == "N":
            return reply_line("n", *self._proximity())
        if letter == "O":
            return reply_line("o", *self._ambient())
        if letter == "L" and not k3 and len(args) == 2 and args[0] in (0, 1):
            led, action = args
            self.leds[led] = 1 - self.leds[led] if action == 2 else int(action != 0)
            return reply_line("l")
        return UNKNOWN_COMMAND_REPLY

    def _proximity(self) -> list[int]:
        """``N``'s fields: the ring's values (a Khepera III's then its two ground sensors
        and a time stamp, ms since the emulator started)."""
        if self.ir_table is None:
            values = self.arena.read_ir()
        else:
            values = table_value(self.arena.read_sensors(), self.ir_table)
        fields = [int(v) for v in np.clip(np.rint(values), 0, khepera.IR_MAX_VALUE)]
        if self.dialect == "khepera3":
            fields += [GROUND_VALUE, GROUND_VALUE, self._stamp_ms()]
        return fields

    def _ambient(self) -> list[int]:
        fields = [AMBIENT_VALUE] * self.arena.body.n_sensors
        if self.dialect == "khepera3":
            fields += [AMBIENT_VALUE, AMBIENT_VALUE, self._stamp_ms()]
        return fields

    def _stamp_ms(self) -> int:
        return int((time.monotonic() - self._started) * 1e3)


def run_until_signalled(emulator: KheperaEmulator, *, link: str | None = None, report_s=5.0):
    """Serve ``emulator`` until SIGINT/SIGTERM (``neuvision emulate khepera``).

    Prints the device path on stdout first (a script reads it from there), then a status
    line on stderr every ``report_s`` seconds; stops the emulator at exit. Called from the
    main thread: it installs its own signal handlers.

    Parameters
    ----------
    emulator : KheperaEmulator
        Not yet started.
    link : str, optional
        A symlink made to the device path (an experiment file can name a fixed port);
        one already there is replaced, and it is removed at exit if it still links here.
    report_s : float
        Seconds between status lines.
    """
    import signal
    import sys

    stop = StopFlag()  # set by signal handlers
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    link_path = Path(link) if link else None
    if link_path is not None:
        if link_path.is_symlink():
            if link_path.exists():  # a live device: another emulator's, most likely
                print(
                    f"neuvision: {link_path} linked to {os.readlink(link_path)}, which is "
                    f"there; it now links to this emulator ({emulator.path})",
                    file=sys.stderr,
                )
            link_path.unlink()
        link_path.symlink_to(emulator.path)
    print(emulator.path, flush=True)
    where = f"{emulator.path}" + (f" (linked as {link_path})" if link_path else "")
    name = emulator.model.name
    print(f"neuvision: {name} emulator on {where}; Ctrl-C ends it", file=sys.stderr)
    # What was built so far lives as long as the process: left out of collections, a full
    # one stays short instead of holding a reply for tens of ms (as a robot never does).
    gc.collect()
    gc.freeze()
    emulator.start()
    try:
        while not stop.wait(report_s):
            x, y, th = emulator.arena.pose
            left, right = emulator.speed_units
            print(
                f"neuvision: emulator: {len(emulator.commands)} commands, wheels "
                f"{left:+d},{right:+d} units, pose x {x:+.3f} m y {y:+.3f} m "
                f"heading {math.degrees(th):+.0f} deg",
                file=sys.stderr,
            )
    finally:
        emulator.stop()
        # only this emulator's link: another emulator may have taken the name over since
        if link_path is not None and _links_to(link_path, emulator.path):
            link_path.unlink()


def _links_to(link: Path, target: str) -> bool:
    """Whether ``link`` is a symlink to ``target``."""
    try:
        return os.readlink(link) == str(target)
    except OSError:  # gone, or not a link
        return False
