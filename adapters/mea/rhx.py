"""The Intan RHX software's TCP interface, as an RHS stimulation/recording controller speaks it.

Two sockets (``shared/reference/devices.md``): the **command port** (5000), where text
commands go — ``set P V``, ``get P`` (answered ``Return: P V``), ``execute A [arg]``; a
failure is a line beginning ``Error`` — and the **spike port** (5002), a stream of 14-byte
records: uint32 magic ``0x3ae2710f``, a 5-character channel name, uint32 timestamp
(samples), uint8 spike id, little-endian.

:class:`RhxDriver` confirms every ``set`` with a ``get``, configures each electrode's pulse
(biphasic, its amplitude and phase width, triggered by ``KeyPressF1``) and fires it, reads
the spike stream on a thread of its own (a record split across reads is joined; a wrong
magic is counted and the stream resynchronised), and maps the instrument's clock to this
machine's (offset and drift, from ``get currenttimestamp``).

Not confirmed on a real RHX: the line end of its replies (taken as ``\\n``) and the exact
spelling of the per-channel stimulation parameters (taken from devices.md).
"""

from __future__ import annotations

import logging
import socket
import struct
import threading
import time
from collections import Counter

import numpy as np

from adapters.mea.driver import ClockMap, spike_arrays
from adapters.mea.layout import ElectrodeLayout
from adapters.mea.safety import BiphasicPulse
from hub.endpoint import DeviceFault

log = logging.getLogger(__name__)

SPIKE_MAGIC = 0x3AE2710F
SPIKE_RECORD = struct.Struct("<I5sIB")  # 14 bytes
TRIGGER = "F1"  # every pulse fires on this key: the channels enabled are those of the step


# A batch of gets is answered by one reply line each. A server that batches small writes
# (Nagle's algorithm, as a Qt socket does by default) holds each line until the previous
# one is acknowledged, and Linux delays acknowledgements by up to 40 ms: acknowledging at
# once after each read keeps a batch's replies coming (Linux only; elsewhere None).
_QUICKACK = getattr(socket, "TCP_QUICKACK", None)


class RhxError(DeviceFault):
    """The instrument answered ``Error …``, did not answer, or a write did not hold."""


def spike_records(buffer: bytearray, counts: Counter) -> list[tuple[str, int]]:
    """Take the complete records off the front of ``buffer``: ``(channel name, timestamp)``.

    An incomplete record stays in the buffer for the next read; bytes before a valid magic
    are dropped and counted (``bad_magic``) — the stream resynchronised on the next magic.
    """
    out = []
    magic = SPIKE_MAGIC.to_bytes(4, "little")
    while len(buffer) >= SPIKE_RECORD.size:
        if buffer[:4] != magic:
            at = buffer.find(magic, 1)
            dropped = at if at > 0 else len(buffer) - 3
            del buffer[:dropped]
            counts["bad_magic"] += 1
            continue
        _, name, timestamp, _ = SPIKE_RECORD.unpack_from(buffer)
        del buffer[: SPIKE_RECORD.size]
        out.append((name.decode("ascii", "replace").rstrip("\0 ").lower(), timestamp))
    return out


def spike_record(name: str, timestamp: int, spike_id: int = 1) -> bytes:
    """One record (the emulator's side)."""
    return SPIKE_RECORD.pack(SPIKE_MAGIC, name.encode("ascii")[:5], timestamp, spike_id)


class RhxDriver:
    """An RHS controller through the RHX software's TCP ports (thread-safe); a
    :class:`~adapters.mea.driver.MeaDriver`.

    Parameters
    ----------
    layout : ElectrodeLayout
        Which instrument channel is which electrode.
    host, command_port, spike_port : str, int, int
        Where RHX listens.
    timeout_s : float
        One command's answer.
    """

    stimulates = True

    def __init__(
        self,
        layout: ElectrodeLayout,
        host: str = "127.0.0.1",
        command_port: int = 5000,
        spike_port: int = 5002,
        timeout_s: float = 1.0,
    ):
        self.layout, self.host = layout, host
        self.command_port, self.spike_port, self.timeout_s = command_port, spike_port, timeout_s
        self.counts: Counter[str] = Counter()
        self.sample_rate_hz = 0.0
        self.clock = ClockMap([])
        self.fault: DeviceFault | None = None
        self._names = layout.index()
        self._cmd: socket.socket | None = None
        self._spk: socket.socket | None = None
        self._reply = b""
        self._lock = threading.Lock()
        self._spikes: list[tuple[int, int, float]] = []  # channel, timestamp, local arrival
        self._spikes_lock = threading.Lock()
        self._stim_state: dict[int, tuple[float, float, bool]] = {}  # channel: amp, phase, on
        self._stop = threading.Event()
        self._reader: threading.Thread | None = None

    # ------------------------------------------------------------ commands

    def _connect(self, port: int) -> socket.socket:
        try:
            sock = socket.create_connection((self.host, port), timeout=self.timeout_s)
        except OSError as exc:
            raise RhxError(f"cannot reach the RHX software at {self.host}:{port}: {exc}") from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return sock

    def _line(self) -> str:
        while b"\n" not in self._reply:
            try:
                chunk = self._cmd.recv(4096)
            except OSError as exc:
                raise RhxError(f"RHX command port: {exc}") from None
            if not chunk:
                raise RhxError("RHX closed the command port")
            if _QUICKACK is not None:  # see _QUICKACK
                self._cmd.setsockopt(socket.IPPROTO_TCP, _QUICKACK, 1)
            self._reply += chunk
        line, _, self._reply = self._reply.partition(b"\n")
        return line.decode("ascii", "replace").strip()

    def _send(self, text: str) -> None:
        try:
            self._cmd.sendall(text.encode("ascii") + b"\n")
        except OSError as exc:
            raise RhxError(f"RHX command port: {exc}") from None

    def get(self, name: str) -> str:
        """``get name`` → its value (the ``Return:`` line's last field)."""
        with self._lock:
            self._send(f"get {name}")
            line = self._line()
        return self._value(name, line)

    def _value(self, name: str, line: str) -> str:
        if line.lower().startswith("error"):
            raise RhxError(f"get {name}: {line}")
        head, _, rest = line.partition(":")
        if head.strip().lower() != "return":
            self.counts["bad_reply"] += 1
            raise RhxError(f"get {name}: unexpected reply {line!r}")
        return rest.strip().split(" ", 1)[-1]

    def set(self, name: str, value) -> None:
        """``set name value``, confirmed by a ``get`` (an ``Error`` or a mismatch raises)."""
        self.set_many([(name, value)])

    def set_many(self, items: list[tuple[str, object]]) -> None:
        """Each ``set name value`` of ``items``, then a ``get`` of each, as one batch of
        ``;``-separated commands: one round trip however many, every write confirmed."""
        if not items:
            return
        texts = [(name, str(v).lower() if isinstance(v, bool) else str(v)) for name, v in items]
        commands = [f"set {name} {text}" for name, text in texts]
        commands += [f"get {name}" for name, _ in texts]
        with self._lock:
            self._send(";".join(commands))
            lines = [self._line() for _ in texts]
        for (name, text), line in zip(texts, lines, strict=True):
            got = self._value(name, line)
            if got.lower() != text.lower() and not _same_number(got, text):
                raise RhxError(f"set {name} {text}: the instrument holds {got!r}")

    def execute(self, action: str, arg: str = "") -> None:
        """``execute action [arg]``: answered by nothing, or an ``Error`` line (checked by
        the next ``get``, which the caller makes when it matters)."""
        with self._lock:
            self._send(f"execute {action} {arg}".strip())

    # ------------------------------------------------------------ life

    def open(self) -> None:
        """Connect, stop the run mode, enable spike output and biphasic stimulation set-up
        on every electrode, and start reading spikes."""
        self._cmd = self._connect(self.command_port)
        self.sample_rate_hz = float(self.get("sampleratehertz"))
        self.set("runmode", "stop")
        for name in self.layout.names:
            self.set(f"{name}.tcpdataoutputenabledspike", True)
            self.set(f"{name}.shape", "Biphasic")
            self.set(f"{name}.source", f"KeyPress{TRIGGER}")
            self.set(f"{name}.stimenabled", False)
        self._spk = self._connect(self.spike_port)
        self._spk.settimeout(0.2)
        self._reader = threading.Thread(target=self._read_spikes, name="rhx-spikes", daemon=True)
        self._reader.start()

    def start(self) -> None:
        """Run mode on; the clock mapped afresh."""
        self.set("runmode", "run")
        self.clock = ClockMap([])
        for _ in range(5):
            self.sample_clock()

    def sample_clock(self) -> None:
        """One (local, instrument) pair: ``get currenttimestamp`` at the middle of its round
        trip."""
        t0 = time.monotonic()
        samples = int(self.get("currenttimestamp"))
        t1 = time.monotonic()
        self.clock.pairs.append(((t0 + t1) / 2, samples / self.sample_rate_hz))
        del self.clock.pairs[:-200]

    def stop(self) -> None:
        """Nothing more delivered: every electrode disabled (as far as the instrument
        answers). Run mode stays on, so the recording goes on: turning it off here stopped
        the spikes and the clock for the rest of a run after a pause or an input timeout."""
        for channel, (amp, phase, on) in list(self._stim_state.items()):
            if on:
                self.set(f"{self.layout.names[channel]}.stimenabled", False)
                self._stim_state[channel] = (amp, phase, False)

    def finish(self) -> None:
        """The run is over: every electrode disabled, then run mode off."""
        self.stop()
        self.set("runmode", "stop")

    def close(self) -> None:
        self._stop.set()
        try:
            if self._cmd is not None:
                self.finish()
        except DeviceFault as exc:
            log.warning("RHX at close: %s", exc)
        for sock in (self._cmd, self._spk):
            if sock is not None:
                sock.close()
        if self._reader is not None:
            self._reader.join(timeout=2.0)

    def report(self) -> dict:
        """Counts and the fitted clock (for ``describe``)."""
        return {**dict(self.counts), **(self.clock.report() if self.clock.pairs else {})}

    # ------------------------------------------------------------ stimulation

    def deliver(self, pulses: list[BiphasicPulse]) -> None:
        """Fire ``pulses`` together: each electrode's parameters set (when changed) and
        uploaded, exactly those electrodes enabled, then one trigger."""
        wanted = {p.channel: p for p in pulses}
        writes, uploads, state = [], [], dict(self._stim_state)
        for channel, (amp, phase, on) in self._stim_state.items():
            if on and channel not in wanted:
                writes.append((f"{self.layout.names[channel]}.stimenabled", False))
                state[channel] = (amp, phase, False)
        for p in pulses:
            name = self.layout.names[p.channel]
            amp, phase, on = self._stim_state.get(p.channel, (None, None, False))
            if (amp, phase) != (p.amplitude_ua, p.phase_us):
                polarity = "NegativeFirst" if p.negative_first else "PositiveFirst"
                writes.append((f"{name}.polarity", polarity))
                for phase_name in ("first", "second"):
                    writes.append((f"{name}.{phase_name}phaseamplitudemicroamps",
                                   f"{p.amplitude_ua:g}"))  # fmt: skip
                    writes.append((f"{name}.{phase_name}phasedurationmicroseconds",
                                   f"{p.phase_us:g}"))  # fmt: skip
            if not on:
                writes.append((f"{name}.stimenabled", True))
            if (amp, phase) != (p.amplitude_ua, p.phase_us) or not on:
                uploads.append(name)
            state[p.channel] = (p.amplitude_ua, p.phase_us, True)
        self.set_many(writes)  # every parameter confirmed before anything is uploaded
        self._stim_state = state
        for name in uploads:
            self.execute("uploadstimparameters", name)
        self.execute("manualstimtriggerpulse", TRIGGER)
        self.counts["triggers"] += 1
        self.counts["pulses"] += len(pulses)

    # ------------------------------------------------------------ spikes

    def _read_spikes(self) -> None:
        buffer = bytearray()
        while not self._stop.is_set():
            try:
                chunk = self._spk.recv(65536)
            except TimeoutError:
                continue
            except OSError as exc:
                if not self._stop.is_set():
                    self.fault = RhxError(f"RHX spike port: {exc}")
                return
            if not chunk:
                if not self._stop.is_set():
                    self.fault = RhxError("RHX closed the spike port")
                return
            now = time.monotonic()
            buffer += chunk
            records = spike_records(buffer, self.counts)
            with self._spikes_lock:
                for name, timestamp in records:
                    channel = self._names.get(name)
                    if channel is None:
                        self.counts["unknown_channel"] += 1
                        continue
                    self._spikes.append((channel, timestamp, now))

    def take_spikes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every spike read since the last call: channel, instrument time (s), arrival."""
        with self._spikes_lock:
            spikes, self._spikes = self._spikes, []
        return spike_arrays(spikes, 1.0 / self.sample_rate_hz)


def _same_number(a: str, b: str) -> bool:
    try:
        return abs(float(a) - float(b)) <= 1e-6 * max(1.0, abs(float(b)))
    except ValueError:
        return False
