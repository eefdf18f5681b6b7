"""An emulator of an Intan RHS controller under the RHX software, backed by a simulated culture.

:class:`IntanEmulator` listens on loopback on a command port and a spike port and answers
the RHX TCP protocol (:mod:`adapters.mea.rhx`) from a :mod:`sim_network` culture seen through
its virtual MEA (``channels = "mea"``), stepped in real time: a channel's spikes are
those of the neurons its electrode records, and a triggered pulse stimulates the neurons
near its electrode, so stimulation evokes real responses. Timestamps count samples at
``sample_rate_hz`` from the start of run mode.

It is an **emulator**: it keeps and returns what ``set`` is given without checking it
against the real software's ranges, knows only the commands the adapter uses plus
``currenttimestamp``, and has no waveform port. Faults can be injected (:class:`Faults`):
the command connection reset, the command port stalled, a malformed spike record.
``neuvision emulate intan`` runs one from the command line.
"""

from __future__ import annotations

import gc
import logging
import socket
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from adapters.mea.layout import ElectrodeLayout
from adapters.mea.rhx import spike_record_bytes
from hub.scheduling import raise_threads
from hub.stopping import StopFlag
from sim_network import Network
from sim_network.config import DEFAULT_CULTURE_FILE, load_config
from sim_network.records import Pulses

log = logging.getLogger(__name__)

DEFAULT_CULTURE = DEFAULT_CULTURE_FILE
SAMPLE_RATE_HZ = 30_000
CHUNK_MS = 0.5  # the culture advances in steps of this much run time


@dataclass
class Faults:
    """Faults to inject (tests)."""

    reset_next_command: bool = False  # close the command connection instead of answering
    stall_until: float = 0.0  # time.monotonic() before which commands are not answered
    malformed_next_spike: bool = False  # garbage before the next spike record
    fired: dict = field(default_factory=lambda: {"reset": 0, "stall": 0, "malformed": 0})


class IntanEmulator:
    """RHX's command and spike ports on loopback, answered by a simulated culture.

    Parameters
    ----------
    culture : path
        A culture file (``configs/culture_1024.toml`` by default); seen through its virtual
        MEA, whose electrodes are the layout's channels in order.
    seed : int
    layout : ElectrodeLayout, optional
        The channel names (default the MCS 60 layout on ports A and B).
    command_port, spike_port : int
        0: free ports, read back from the attributes of the same names.
    realtime_priority : int
        > 0: the emulator's threads run under ``SCHED_FIFO`` at this priority (refused:
        ordinary scheduling, logged). A realtime run puts the hub's and the endpoints'
        threads there (:mod:`hub.scheduling`); an instrument on the same machine under the
        ordinary scheduler then waits for a CPU until every one of them sleeps: 1–3 ms
        for a command's answer at a step's start, measured here.
    """

    def __init__(
        self,
        culture: str | Path = DEFAULT_CULTURE,
        *,
        seed: int = 1,
        layout: ElectrodeLayout | None = None,
        command_port: int = 0,
        spike_port: int = 0,
        realtime_priority: int = 0,
    ):
        cfg = load_config(culture, ['channels="mea"'])
        self.net = Network(cfg, seed=seed)
        # Compiled now, not at the run's first chunk: compiling then put the culture seconds
        # behind real time, and while it caught up every pulse's command waited for it
        # (a first hybrid run: 124 late steps of 2,000, every tenth).
        self.net.warm_up()
        self.layout = layout or ElectrodeLayout.mcs60(cfg.mea.pitch_um)
        if self.layout.n != self.net.channels.channel.size:
            raise ValueError(
                f"the layout has {self.layout.n} channels, the culture's MEA "
                f"{self.net.channels.channel.size}"
            )
        self.faults = Faults()
        self.realtime_priority = realtime_priority
        self.values: dict[str, str] = {"sampleratehertz": str(SAMPLE_RATE_HZ), "runmode": "stop"}
        self.uploaded: dict[str, dict[str, str]] = {}
        self._channel_values: dict[str, dict[str, str]] = {}  # a-010: {stimenabled: true, …}
        self.triggers: list[tuple[float, list[int]]] = []  # (time, channels fired)
        self.commands = 0
        self._index = self.layout.index()
        self._record_names = np.array([n.encode("ascii")[:5] for n in self.layout.names], "S5")
        self._run_t0: float | None = None
        self._pending: list[Pulses] = []
        self._lock = threading.Lock()
        self._stop = StopFlag()
        self._spike_clients: list[socket.socket] = []
        self._cmd_server = self._listen(command_port)
        self._spk_server = self._listen(spike_port)
        self.command_port = self._cmd_server.getsockname()[1]
        self.spike_port = self._spk_server.getsockname()[1]
        self._threads: list[threading.Thread] = []

    @staticmethod
    def _listen(port: int) -> socket.socket:
        server = socket.create_server(("127.0.0.1", port), reuse_port=False)
        server.settimeout(0.2)
        return server

    # ------------------------------------------------------------ running

    def start(self) -> IntanEmulator:
        """Serve both ports and run the culture, each on a thread of its own; returns self."""
        for target in (self._accept_commands, self._accept_spikes, self._simulate):
            t = threading.Thread(
                target=self._raised, args=(target,), daemon=True, name=f"intan-{target.__name__}"
            )
            t.start()
            self._threads.append(t)
        return self

    def _raised(self, target, *args) -> None:
        """Run ``target`` on this thread, under ``SCHED_FIFO`` if asked (not inherited)."""
        if self.realtime_priority:
            got = raise_threads(self.realtime_priority, [threading.get_native_id()])
            if got.policy != "fifo":
                log.warning("emulator: realtime priority not applied: %s", got.reason)
        target(*args)

    def stop(self) -> None:
        """Stop serving: the threads ended, both ports and the spike clients closed."""
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2.0)
        for sock in (self._cmd_server, self._spk_server, *self._spike_clients):
            sock.close()

    def __enter__(self) -> IntanEmulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def timestamp(self, now: float | None = None) -> int:
        """Samples since run mode began (0 when stopped)."""
        if self._run_t0 is None:
            return 0
        now = time.monotonic() if now is None else now
        return int((now - self._run_t0) * SAMPLE_RATE_HZ)

    # ------------------------------------------------------------ command port

    def _accept_commands(self) -> None:
        """One command client at a time, as the RHX software serves them (it stops
        listening while one is connected, and a second is refused; here a second waits,
        unanswered, until the first leaves): two runs cannot drive one instrument."""
        while not self._stop.is_set():
            try:
                conn, _ = self._cmd_server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self._serve_commands(conn)

    def _serve_commands(self, conn: socket.socket) -> None:
        conn.settimeout(0.2)
        buffer = b""
        with conn:
            while not self._stop.is_set():
                try:
                    chunk = conn.recv(4096)
                except TimeoutError:
                    continue
                except OSError:
                    return
                if not chunk:
                    return
                buffer += chunk
                # Replies to what one read brought go out in one write, as the RHX
                # software's socket (Qt's, which buffers writes until its event loop
                # runs) sends them.
                replies = []
                while b"\n" in buffer or b";" in buffer:
                    cut = min(i for i in (buffer.find(b"\n"), buffer.find(b";")) if i >= 0)
                    line, buffer = (
                        buffer[:cut].decode("ascii", "replace").strip(),
                        buffer[cut + 1 :],
                    )
                    if not line:
                        continue
                    if self.faults.reset_next_command:
                        self.faults.reset_next_command = False
                        self.faults.fired["reset"] += 1
                        conn.close()
                        return
                    while time.monotonic() < self.faults.stall_until and not self._stop.is_set():
                        self.faults.fired["stall"] += 1
                        self._stop.wait(0.05)
                    reply = self._command(line)
                    if reply:
                        replies.append(reply.encode("ascii") + b"\n")
                if replies:
                    conn.sendall(b"".join(replies))

    def _command(self, line: str) -> str:
        self.commands += 1
        verb, _, rest = line.partition(" ")
        verb = verb.lower()
        if verb == "get":
            name = rest.strip().lower()
            if name == "currenttimestamp":
                return f"Return: CurrentTimestamp {self.timestamp()}"
            if name not in self.values:
                return f"Error: unknown parameter {rest.strip()}"
            return f"Return: {rest.strip()} {self.values[name]}"
        if verb == "set":
            name, _, value = rest.strip().partition(" ")
            name = name.lower()
            if not value:
                return f"Error: set {name} needs a value"
            if name == "runmode":
                self._set_runmode(value.lower())
            value = value.lower() if value.lower() in ("true", "false") else value
            self.values[name] = value
            channel, dot, parameter = name.partition(".")
            if dot:
                self._channel_values.setdefault(channel, {})[parameter] = value
            return ""
        if verb == "execute":
            action, _, arg = rest.strip().partition(" ")
            action = action.lower()
            if action == "uploadstimparameters":
                channel = arg.strip().lower()
                self.uploaded[channel] = dict(self._channel_values.get(channel, {}))
                return ""
            if action == "manualstimtriggerpulse":
                self._trigger(arg.strip().upper())
                return ""
            return f"Error: unknown action {action}"
        return f"Error: unknown command {verb}"

    def _set_runmode(self, mode: str) -> None:
        with self._lock:
            if mode == "run" and self._run_t0 is None:
                self._run_t0 = time.monotonic()
                self._sim_origin_ms = self.net.t_ms
            elif mode == "stop":
                self._run_t0 = None
                self._pending.clear()

    def _trigger(self, key: str) -> None:
        """Fire every uploaded, enabled channel whose source is this key."""
        fired, amps, widths = [], [], []
        for name, p in self.uploaded.items():
            if p.get("stimenabled") != "true" or p.get("source", "").upper() != f"KEYPRESS{key}":
                continue
            channel = self._index.get(name)
            if channel is None:
                continue
            phase_us = float(p.get("firstphasedurationmicroseconds", 0))
            fired.append(channel)
            amps.append(float(p.get("firstphaseamplitudemicroamps", 0)))
            widths.append(2 * phase_us / 1e3)  # both phases drive the neurons near it
        self.triggers.append((time.monotonic(), fired))
        if fired and self._run_t0 is not None:
            pulses = Pulses(
                channel=np.array(fired, np.uint32),
                amplitude_ua=np.array(amps, np.float32),
                width_ms=np.array(widths, np.float32),
                onset_ms=np.zeros(len(fired), np.float32),
            )
            with self._lock:
                self._pending.append(pulses)

    # ------------------------------------------------------------ spike port

    def _accept_spikes(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._spk_server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._spike_clients.append(conn)

    def _send_spikes(self, data: bytes) -> None:
        for conn in list(self._spike_clients):
            try:
                conn.sendall(data)
            except OSError:
                self._spike_clients.remove(conn)

    # ------------------------------------------------------------ the culture

    def _simulate(self) -> None:
        """Keep the culture at wall-clock time while in run mode, sending its spikes."""
        while not self._stop.is_set():
            with self._lock:
                t0 = self._run_t0
            if t0 is None:
                self._stop.wait(0.01)
                continue
            behind_ms = (time.monotonic() - t0) * 1e3 - (self.net.t_ms - self._sim_origin_ms)
            if behind_ms < CHUNK_MS:
                self._stop.wait((CHUNK_MS - behind_ms) / 1e3)
                continue
            with self._lock:
                pending, self._pending = self._pending, []
            pulses = _merged(pending)
            spikes = self.net.run(CHUNK_MS, pulses)
            if spikes.channel.size == 0:
                continue
            samples = ((spikes.t_ms - self._sim_origin_ms) * SAMPLE_RATE_HZ / 1e3).astype(np.int64)
            data = spike_record_bytes(self._record_names[spikes.channel], samples)
            if self.faults.malformed_next_spike:
                self.faults.malformed_next_spike = False
                self.faults.fired["malformed"] += 1
                data = b"\x00garbage" + data
            self._send_spikes(data)


def _merged(pending: list[Pulses]) -> Pulses | None:
    if not pending:
        return None
    if len(pending) == 1:
        return pending[0]
    return Pulses(
        channel=np.concatenate([p.channel for p in pending]),
        amplitude_ua=np.concatenate([p.amplitude_ua for p in pending]),
        width_ms=np.concatenate([p.width_ms for p in pending]),
        onset_ms=np.concatenate([p.onset_ms for p in pending]),
    )


def run_until_signalled(emulator: IntanEmulator, report_s: float = 5.0) -> None:
    """Serve until SIGINT/SIGTERM (``neuvision emulate intan``); stop the emulator at exit.

    Called from the main thread: it installs its own signal handlers. It puts this thread
    under ``SCHED_FIFO`` too when the emulator's ``realtime_priority`` asks for it.

    Parameters
    ----------
    emulator : IntanEmulator
        Not yet started.
    report_s : float
        Seconds between status lines on stderr.
    """
    import signal
    import sys

    stop = StopFlag()  # set by signal handlers
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    # The culture and everything built so far live as long as the process: left out of
    # collections, a full one stays short instead of holding the instrument's replies.
    gc.collect()
    gc.freeze()
    emulator.start()
    # this thread too: one under the ordinary scheduler holding the interpreter would keep
    # the raised ones waiting for it (a priority inversion)
    raise_threads(emulator.realtime_priority)
    print(
        f"neuvision: Intan RHX emulator: commands on 127.0.0.1:{emulator.command_port}, spikes "
        f"on 127.0.0.1:{emulator.spike_port} ({emulator.layout.n} electrodes); Ctrl-C ends it",
        file=sys.stderr,
        flush=True,
    )
    try:
        while not stop.wait(report_s):
            print(
                f"neuvision: emulator: run mode {emulator.values.get('runmode')}, "
                f"{emulator.commands} commands, {len(emulator.triggers)} triggers, culture at "
                f"{emulator.net.t_ms / 1e3:.1f} s",
                file=sys.stderr,
                flush=True,
            )
    finally:
        emulator.stop()
