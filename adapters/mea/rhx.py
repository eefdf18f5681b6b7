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
from collections.abc import Callable

import numpy as np

from adapters.guard import StopGuard
from adapters.mea.driver import ClockMap
from adapters.mea.layout import ElectrodeLayout
from adapters.mea.safety import BiphasicPulse
from hub.endpoint import DeviceFault

log = logging.getLogger(__name__)

SPIKE_MAGIC = 0x3AE2710F
SPIKE_RECORD = struct.Struct("<I5sIB")  # 14 bytes
SPIKE_DTYPE = np.dtype(
    [("magic", "<u4"), ("name", "S5"), ("timestamp", "<u4"), ("spike_id", "u1")]
)  # the same record, packed, for numpy
_MAGIC_BYTES = SPIKE_MAGIC.to_bytes(4, "little")
TRIGGER = "F1"  # every pulse fires on this key: the channels enabled are those of the step


# A batch of gets is answered by one reply line each. A server that batches small writes
# (Nagle's algorithm, as a Qt socket does by default) holds each line until the previous
# one is acknowledged, and Linux delays acknowledgements by up to 40 ms: acknowledging at
# once after each read keeps a batch's replies coming (Linux only; elsewhere None).
_QUICKACK = getattr(socket, "TCP_QUICKACK", None)


class RhxError(DeviceFault):
    """The instrument answered ``Error …``, did not answer, or a write did not hold."""


def spike_records(buffer: bytearray, counts: Counter) -> np.ndarray:
    """Take the complete records off the front of ``buffer``, as :data:`SPIKE_DTYPE` records.

    An incomplete record stays in the buffer for the next read; bytes before a valid magic
    are dropped and counted (``bad_magic``) — the stream resynchronised on the next magic.
    Records are read as one array: a burst's thousands of records would otherwise hold the
    interpreter for milliseconds, and the thread firing pulses with it.

    Parameters
    ----------
    buffer : bytearray
        The bytes read from the spike port and not yet taken; changed in place.
    counts : Counter
        Where ``bad_magic`` is counted, once per resynchronisation.
    """
    out = []
    while len(buffer) >= SPIKE_RECORD.size:
        if buffer[:4] != _MAGIC_BYTES:
            at = buffer.find(_MAGIC_BYTES, 1)
            dropped = at if at > 0 else len(buffer) - 3
            del buffer[:dropped]
            counts["bad_magic"] += 1
            continue
        n = len(buffer) // SPIKE_RECORD.size
        records = np.frombuffer(bytes(buffer[: n * SPIKE_RECORD.size]), SPIKE_DTYPE)
        good = records["magic"] == SPIKE_MAGIC
        if not good.all():  # good up to the first bad one; the loop resynchronises there
            n = int(good.argmin())
            records = records[:n]
        out.append(records)
        del buffer[: n * SPIKE_RECORD.size]
    if len(out) == 1:
        return out[0]
    return np.concatenate(out) if out else np.zeros(0, SPIKE_DTYPE)


def spike_record_bytes(names: np.ndarray, timestamps: np.ndarray, spike_id: int = 1) -> bytes:
    """The spike port's bytes for a batch of spikes (the emulator's side).

    Parameters
    ----------
    names : S5 array
        Each spike's channel name.
    timestamps : uint32 array_like
        Each spike's time, in samples.
    spike_id : int
        The id every record carries.
    """
    records = np.empty(len(names), SPIKE_DTYPE)
    records["magic"] = SPIKE_MAGIC
    records["name"] = names
    records["timestamp"] = timestamps
    records["spike_id"] = spike_id
    return records.tobytes()


def spike_record(name: str, timestamp: int, spike_id: int = 1) -> bytes:
    """One spike record's bytes.

    Parameters
    ----------
    name : str
        The channel name (ASCII; its first 5 characters kept).
    timestamp : int
        The spike's time, in samples.
    spike_id : int
        The record's spike id.
    """
    return SPIKE_RECORD.pack(SPIKE_MAGIC, name.encode("ascii")[:5], timestamp, spike_id)


#: how long a command's reply may take (a slower one is a fault)
COMMAND_TIMEOUT_S = 1.0


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
    freeze_s : float
        This process frozen (no :meth:`beat`) this long, its stop guard makes the
        instrument safe; 0: only the process's end does.
    """

    stimulates = True

    def __init__(
        self,
        layout: ElectrodeLayout,
        host: str = "127.0.0.1",
        command_port: int = 5000,
        spike_port: int = 5002,
        timeout_s: float = COMMAND_TIMEOUT_S,
        freeze_s: float = 0.0,
    ):
        self.layout, self.host = layout, host
        self.freeze_s = freeze_s  # the stop guard's, for a frozen process (adapters.guard)
        self.command_port, self.spike_port, self.timeout_s = command_port, spike_port, timeout_s
        self.counts: Counter[str] = Counter()
        self.sample_rate_hz = 0.0
        self.clock = ClockMap([])
        self.fault: DeviceFault | None = None
        self._names = layout.index()
        self._by_record_name: dict[bytes, int] = {}  # as the records spell it
        self._cmd: socket.socket | None = None
        self._spk: socket.socket | None = None
        # why the command port may not be used again (a command with no answer: a reply
        # that comes later would be taken for the next command's), or None
        self._cmd_failed: str | None = None
        self._reply = b""
        self._lock = threading.Lock()
        self._spikes: list[tuple[np.ndarray, np.ndarray, float]] = []  # per read: channel,
        # timestamp, local arrival
        self._spikes_lock = threading.Lock()
        self.on_spikes: Callable[[], None] | None = None  # called after each read of spikes
        self._held: dict[str, str] = {}  # parameter → the value the instrument confirmed
        self._enabled: set[int] = set()  # channels confirmed stimenabled true
        self._stop = threading.Event()
        self._closed = False
        self._reader: threading.Thread | None = None
        self.guard: StopGuard | None = None

    # ------------------------------------------------------------ commands

    def _connect(self, port: int) -> socket.socket:
        try:
            sock = socket.create_connection((self.host, port), timeout=self.timeout_s)
        except OSError as exc:
            raise RhxError(f"cannot reach the RHX software at {self.host}:{port}: {exc}") from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return sock

    def _failed(self, why: str) -> RhxError:
        """The command port failed: it is not used again (the stop is the guard's)."""
        self._cmd_failed = self._cmd_failed or why
        return RhxError(f"RHX command port: {why}")

    def _line(self) -> str:
        while b"\n" not in self._reply:
            try:
                chunk = self._cmd.recv(4096)
            except OSError as exc:
                raise self._failed(str(exc)) from None
            if not chunk:
                raise self._failed("closed by the RHX software")
            if _QUICKACK is not None:  # see _QUICKACK
                self._cmd.setsockopt(socket.IPPROTO_TCP, _QUICKACK, 1)
            self._reply += chunk
        line, _, self._reply = self._reply.partition(b"\n")
        return line.decode("ascii", "replace").strip()

    def _send(self, text: str) -> None:
        if self._cmd_failed is not None:
            raise RhxError(f"RHX command port failed earlier ({self._cmd_failed}): not used again")
        try:
            self._cmd.sendall(text.encode("ascii") + b"\n")
        except OSError as exc:
            raise self._failed(str(exc)) from None

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
        """``set name value``, confirmed by a ``get``.

        Parameters
        ----------
        name : str
            The parameter (``runmode``, ``a-010.stimenabled``).
        value : object
            Written with ``str`` (a bool as ``true``/``false``); read back equal, ignoring
            case (numbers: to 1e-6 relative).

        Raises
        ------
        RhxError
            The instrument answered ``Error``, did not answer, or holds another value.
        """
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
        self._held.update(texts)
        for name, text in texts:
            electrode, _, parameter = name.partition(".")
            if parameter == "stimenabled" and electrode in self._names:
                (self._enabled.add if text == "true" else self._enabled.discard)(
                    self._names[electrode]
                )

    # ------------------------------------------------------------ life

    def open(self) -> None:
        """Connect, stop the run mode, enable spike output and biphasic stimulation set-up
        on every electrode, and start reading spikes.

        The stop guard is armed once the command port answers as an RHX does (its sample
        rate): a service that is not one is sent nothing more. If a later step fails (the
        spike port not there, a setting refused), the instrument is made safe and the guard
        released here, and the failure is what is raised."""
        self._cmd = self._connect(self.command_port)
        try:
            try:
                rate = self.get("sampleratehertz")
            except RhxError as exc:
                raise RhxError(
                    f"the RHX software at {self.host}:{self.command_port} did not answer its "
                    f"first question ({exc}); it serves one client at a time: is another run "
                    "or program connected to it?"
                ) from None
            try:
                self.sample_rate_hz = float(rate)
            except ValueError:
                raise RhxError(
                    f"the service at {self.host}:{self.command_port} does not answer as the "
                    f"RHX software (its sample rate: {rate!r})"
                ) from None
        except BaseException:
            self._cmd.close()
            self._cmd = None
            raise
        self._guard()
        try:
            self.set("runmode", "stop")
            for name in self.layout.names:
                self.set(f"{name}.tcpdataoutputenabledspike", True)
                self.set(f"{name}.shape", "Biphasic")
                self.set(f"{name}.source", f"KeyPress{TRIGGER}")
                self.set(f"{name}.stimenabled", False)
            self._spk = self._connect(self.spike_port)
        except BaseException:
            self.close()
            raise
        self._spk.settimeout(0.2)
        self._reader = threading.Thread(target=self._read_spikes, name="rhx-spikes", daemon=True)
        self._reader.start()

    def _guard(self) -> None:
        """A :class:`~adapters.guard.StopGuard` on the command port: if this process ends
        without :meth:`close` (SIGKILL, the OOM killer), or, with ``freeze_s``, stops
        beating for that long (frozen), every electrode is disabled and uploaded and run
        mode stopped, as :meth:`finish` would (after a line end, which ends any command
        this process was cut off in)."""
        names = self.layout.names
        stop = ";".join(
            [f"set {n}.stimenabled false" for n in names]
            + [f"execute uploadstimparameters {n}" for n in names]
            + ["set runmode stop"]
        )
        where = f"{self.host}:{self.command_port}"
        self.guard = StopGuard(
            self._cmd.fileno(), f"\n{stop}\n".encode("ascii"), f"the RHX at {where}",
            "every electrode disabled and uploaded, run mode stop,", freeze_s=self.freeze_s,
        )  # fmt: skip

    def beat(self) -> bool:
        """This process lives (the endpoint's device worker, at least every 0.1 s); True
        when the stop guard made the instrument safe since the last beat (this process
        was frozen for ``freeze_s``)."""
        return self.guard is not None and self.guard.beat()

    def rest(self) -> None:
        """The beats stop on purpose (the device worker ends): no freeze."""
        if self.guard is not None:
            self.guard.rest()

    def start(self) -> None:
        """Run mode on; the clock mapped afresh; each pulse parameter written afresh at its
        first use (one changed at the instrument between runs is not trusted)."""
        self._held = {k: v for k, v in self._held.items() if k.endswith(".stimenabled")}
        self.set("runmode", "run")
        self.clock = ClockMap([])
        for _ in range(5):
            self.sample_clock()

    def sample_clock(self) -> None:
        """One (local, instrument) pair: ``get currenttimestamp`` at the middle of its round
        trip. Raises the spike reader's fault, if it found the spike port lost (the run
        must not go on without its spikes)."""
        if self.fault is not None:
            raise self.fault
        t0 = time.monotonic()
        samples = int(self.get("currenttimestamp"))
        t1 = time.monotonic()
        self.clock.pairs.append(((t0 + t1) / 2, samples / self.sample_rate_hz))
        del self.clock.pairs[:-200]

    def stop(self) -> None:
        """Nothing more delivered: every electrode disabled and uploaded (as far as the
        instrument answers). Run mode stays on, so the recording goes on: turning it off here
        stopped the spikes and the clock for the rest of a run after a pause or an input
        timeout. After :meth:`close`, nothing: the instrument was made safe then."""
        if self._closed:
            return
        self._configure({f"{self.layout.names[c]}.stimenabled": "false" for c in self.enabled})

    @property
    def enabled(self) -> frozenset[int]:
        """The channels whose stimulation the instrument confirmed enabled."""
        return frozenset(self._enabled)

    def finish(self) -> None:
        """The run is over: every electrode disabled, then run mode off (after
        :meth:`close`, nothing)."""
        if self._closed:
            return
        self.stop()
        self.set("runmode", "stop")

    def close(self) -> None:
        """Make the instrument safe (:meth:`finish`) and let it go: sockets closed, the
        spike reader ended, the stop guard released. A command port that failed is left to
        the stop guard, which writes its stop there. Called again, nothing."""
        if self._closed:
            return
        if self._cmd is not None and self._cmd_failed is None:
            try:
                self.finish()
            except DeviceFault as exc:
                log.warning("RHX at close: %s", exc)
        self._closed = True
        self._stop.set()
        if self.guard is not None:
            if self._cmd_failed is None:
                self.guard.release()
            else:  # its stop, written on the connection, is read when the RHX answers again
                log.warning(
                    "RHX at close: the command port failed (%s): the stop guard writes the "
                    "stop on it", self._cmd_failed,
                )  # fmt: skip
                self.guard.abandon()
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
        """Fire ``pulses`` together: exactly their electrodes enabled, each with its pulse,
        then one trigger.

        Only the parameters that differ from what the instrument confirmed are written (a
        pulse of a new amplitude: its two amplitudes), in one round trip, and every
        electrode written is uploaded — a disabled one too, or it would fire again with its
        last upload.
        """
        wanted = {p.channel for p in pulses}
        settings = {f"{self.layout.names[c]}.stimenabled": "false" for c in self.enabled - wanted}
        for p in pulses:
            name, amp, phase = (
                self.layout.names[p.channel],
                f"{p.amplitude_ua:g}",
                f"{p.phase_us:g}",
            )
            settings |= {
                f"{name}.polarity": "NegativeFirst" if p.negative_first else "PositiveFirst",
                f"{name}.firstphaseamplitudemicroamps": amp,
                f"{name}.secondphaseamplitudemicroamps": amp,
                f"{name}.firstphasedurationmicroseconds": phase,
                f"{name}.secondphasedurationmicroseconds": phase,
                f"{name}.stimenabled": "true",
            }
        self._configure(settings, then=f"execute manualstimtriggerpulse {TRIGGER}")
        self.counts["triggers"] += 1
        self.counts["pulses"] += len(pulses)

    def _configure(self, settings: dict[str, str], then: str = "") -> None:
        """Write the ``settings`` the instrument does not hold, confirm them (one round
        trip), then upload each electrode written and send ``then``, in one write."""
        writes = [(k, v) for k, v in settings.items() if self._held.get(k) != v]
        self.set_many(writes)  # every parameter confirmed before anything is uploaded
        names = dict.fromkeys(name.partition(".")[0] for name, _ in writes)
        commands = [f"execute uploadstimparameters {name}" for name in names]
        if then:
            commands.append(then)
        if commands:
            with self._lock:
                self._send(";".join(commands))

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
            if not records.size:
                continue
            channel = np.array([self._name_channel(n) for n in records["name"].tolist()])
            known = channel >= 0
            self.counts["unknown_channel"] += int(known.size - known.sum())
            with self._spikes_lock:
                self._spikes.append((channel[known], records["timestamp"][known], now))
            if self.on_spikes is not None:
                self.on_spikes()

    def _name_channel(self, name: bytes) -> int:
        """A record's channel name → the layout's channel (-1: not in the layout)."""
        channel = self._by_record_name.get(name)
        if channel is None:
            text = name.decode("ascii", "replace").rstrip("\0 ").lower()
            channel = self._by_record_name[name] = self._names.get(text, -1)
        return channel

    def take_spikes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every spike read since the last call: channel, instrument time (s), arrival."""
        with self._spikes_lock:
            reads, self._spikes = self._spikes, []
        if not reads:
            return np.zeros(0, np.uint32), np.zeros(0), np.zeros(0)
        channel = np.concatenate([c for c, _, _ in reads]).astype(np.uint32)
        inst_s = np.concatenate([t for _, t, _ in reads]) / self.sample_rate_hz
        arrived = np.concatenate([np.full(c.size, now) for c, _, now in reads])
        return channel, inst_s, arrived


def _same_number(a: str, b: str) -> bool:
    try:
        return abs(float(a) - float(b)) <= 1e-6 * max(1.0, abs(float(b)))
    except ValueError:
        return False
