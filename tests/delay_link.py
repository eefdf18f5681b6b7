"""A slow network link on loopback: a TCP relay that holds every chunk it carries for a delay
(± jitter, order kept), in each direction, as ``tc netem delay`` would on a link. It stands
in where the kernel has no ``sch_netem``: an endpoint reaches its hub through it, so every
message between them is delayed. Used by the tests and ``bench/remote.py``.
"""

from __future__ import annotations

import json
import queue
import random
import secrets
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from hub.bus import free_tcp_port
from hub.config import load_config
from hub.launch import die_with_parent
from hub.record import read_run
from tests.netns import run_hub

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = "configs/closed_loop.toml"


class DelayLink:
    """Listen on a free loopback port; relay each connection to ``target_port`` with every
    chunk held ``delay_ms`` ± ``jitter_ms`` (uniform, seeded) in either direction. A chunk
    never overtakes the one before it (TCP keeps order), so the jitter delays, never
    reorders."""

    def __init__(self, target_port: int, delay_ms: float, jitter_ms: float = 0.0, seed: int = 0):
        self.target_port = target_port
        self.delay_s, self.jitter_s = delay_ms / 1e3, jitter_ms / 1e3
        self._rng = random.Random(seed)
        self._server = socket.create_server(("127.0.0.1", 0))
        self._server.settimeout(0.2)
        self.port = self._server.getsockname()[1]
        self._closed = threading.Event()
        self._sockets: list[socket.socket] = []
        self.chunks = 0  # chunks relayed, both directions
        threading.Thread(target=self._accept, name="delay-accept", daemon=True).start()

    def close(self) -> None:
        self._closed.set()
        for sock in (self._server, *self._sockets):
            try:
                sock.close()
            except OSError:
                pass

    def __enter__(self) -> DelayLink:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                near, _ = self._server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            try:
                far = socket.create_connection(("127.0.0.1", self.target_port), timeout=5)
            except OSError:
                near.close()
                continue
            for sock in (near, far):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                sock.settimeout(None)
                self._sockets.append(sock)
            for src, dst in ((near, far), (far, near)):
                held: queue.SimpleQueue = queue.SimpleQueue()
                threading.Thread(target=self._read, args=(src, held), daemon=True).start()
                threading.Thread(target=self._write, args=(dst, held), daemon=True).start()

    def _read(self, src: socket.socket, held: queue.SimpleQueue) -> None:
        release = 0.0
        while True:
            try:
                data = src.recv(65536)
            except OSError:
                data = b""
            if not data:
                held.put(None)
                return
            delay = self.delay_s + self._rng.uniform(-self.jitter_s, self.jitter_s)
            release = max(release, time.monotonic() + max(delay, 0.0))
            held.put((release, data))

    def _write(self, dst: socket.socket, held: queue.SimpleQueue) -> None:
        while (item := held.get()) is not None:
            release, data = item
            wait = release - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            try:
                dst.sendall(data)
            except OSError:
                return
            self.chunks += 1
        try:
            dst.shutdown(socket.SHUT_WR)
        except OSError:
            pass


def delayed_closed_loop(tmp_path: Path, name: str, delay_ms: float, jitter_ms: float, *extra):
    """The paper's closed loop in realtime with the body and the culture each reaching the
    hub through a :class:`DelayLink` of ``delay_ms`` ± ``jitter_ms`` (``extra`` overrides
    after); returns the run's record, its result and the links' chunk counts."""
    port = free_tcp_port()
    session = f"test-{secrets.token_hex(4)}"
    common = [
        "experiment.seed=3",
        'loop.mode="realtime"',
        f"bus.session={json.dumps(session)}",
        f"bus.listen={json.dumps([f'tcp/127.0.0.1:{port}'])}",
        'body.launch="external"',
        'culture.launch="external"',
        *extra,
    ]
    cfg = load_config(EXPERIMENT, common)
    links = {role: DelayLink(port, delay_ms, jitter_ms, seed=i) for i, role in
             enumerate(("body", "culture"))}  # fmt: skip
    procs = []
    try:
        for role, link in links.items():
            argv = [sys.executable, "-m", "hub.cli", "endpoint", role, EXPERIMENT, "--once"]
            for item in common + [f'bus.connect=["tcp/127.0.0.1:{link.port}"]']:
                argv += ["--set", item]
            log = open(tmp_path / f"{name}-{role}.log", "wb")
            procs.append(
                subprocess.Popen(
                    argv, stdout=log, stderr=subprocess.STDOUT, preexec_fn=die_with_parent, cwd=ROOT
                )  # fmt: skip
            )
        run_dir = tmp_path / name
        run_dir.mkdir()
        result = run_hub(cfg, run_dir, procs)
    finally:
        for p in procs:  # run_hub reaped them, unless an endpoint failed to start
            if p.poll() is None:
                p.kill()
                p.wait()
        for link in links.values():
            link.close()
    return read_run(run_dir), result, {role: link.chunks for role, link in links.items()}
