"""The web server: the page, its assets, and a websocket per page that carries frames.

Starlette serves ``/`` (the page) and ``/static/`` (its script and style, shipped in the
package: no CDN, no build step) and ``/ws``. One task, the *pump*, runs at the frames
rate: in a worker thread it lets the source feed the state (:meth:`tick`) and builds each
page's frame (:meth:`FrameState.frame`); a page whose last frame is still being sent
gets none this time (it is counted as dropped) and everything since in its next one. The
page sends controls back on the same websocket (``{"cmd": ...}``), which go to the source:
the hub's ``hub/control`` live, the replay's clock in a replay.

:func:`serve` runs it with uvicorn on a socket bound first, so that a port already taken
is one line (:class:`ServeError`), and port 0 gets a free one.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import json
import logging
import math
import signal
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from typing import Protocol

import msgspec
import uvicorn
from starlette.applications import Starlette
from starlette.responses import FileResponse, JSONResponse
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from .state import FrameState, Reader

log = logging.getLogger(__name__)

STATIC = resources.files("dashboard") / "static"


class Source(Protocol):
    """What feeds the state: :class:`~dashboard.observer.BusObserver` or
    :class:`~dashboard.replay.ReplaySource`."""

    def start(self) -> None:
        """Begin feeding (called once, in a worker thread, as the server starts)."""

    def page_opened(self) -> None:
        """A page connected (called in a worker thread)."""

    def tick(self) -> None:
        """Feed the state what came since the last tick (the caller holds its lock)."""

    def command(self, message: dict) -> dict:
        """A page's control (``{"cmd": ...}``); the reply as ``{ok, state, reason}``."""

    def close(self) -> None:
        """Stop feeding and release what `start` took (as the server ends)."""


class ServeError(RuntimeError):
    """The page cannot be served (the port is taken); the message says where.

    Parameters
    ----------
    message : str
        What failed, and where.
    bad_address : bool
        True when the address itself is wrong (a host that is not this machine's or has
        no address), not the machine's state (a port taken); kept as ``bad_address``.
    """

    def __init__(self, message: str, *, bad_address: bool = False):
        super().__init__(message)
        self.bad_address = bad_address


@dataclass(eq=False)
class Page:
    """One connected page: its websocket, its place in the state, its frame counts."""

    ws: WebSocket
    reader: Reader = field(default_factory=Reader)
    busy: bool = False  # a frame is being sent
    sent: int = 0
    dropped: int = 0
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)

    async def send(self, text: str) -> None:
        """Send one message, after any other send to this page has ended."""
        async with self.lock:
            await self.ws.send_text(text)


class Dashboard:
    """The app: a source feeds the state; frames go to every page ``fps`` times a second.

    Parameters
    ----------
    source : Source
        Started and closed with the app; ticked before each round of frames.
    state : FrameState
        What the pages are shown.
    fps : float
        Frames a second, > 0.
    """

    def __init__(self, source: Source, state: FrameState, fps: float = 30.0):
        self.source = source
        self.state = state
        self.interval_s = 1.0 / fps
        self.pages: set[Page] = set()
        self.ticks = 0
        # (wall, CPU) when the first step was shown: the process's share from then on is
        # its cost while a run steps, apart from its start-up
        self.stepping_since: tuple[float, float] | None = None
        self.app = Starlette(
            routes=[
                Route("/", self.index),
                Route("/frame", self.frame_json),
                Mount("/static", StaticFiles(directory=str(STATIC)), name="static"),
                WebSocketRoute("/ws", self.websocket),
            ],
            lifespan=self.lifespan,
        )

    @contextlib.asynccontextmanager
    async def lifespan(self, app):
        """Starlette's lifespan: start the source and the pump, and at the end stop both
        and log the process's CPU use."""
        await asyncio.to_thread(self.source.start)
        pump = asyncio.create_task(self.pump())
        started = (time.monotonic(), time.process_time())
        try:
            yield
        finally:
            pump.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await pump
            await asyncio.to_thread(self.source.close)
            wall, cpu, share = _used_since(started)
            log.info(
                "served %d ticks in %.1f s; the dashboard's process used %.2f s of CPU (%.1f %% "
                "of a core)", self.ticks, wall, cpu, share,
            )  # fmt: skip
            if self.stepping_since is not None:
                wall, cpu, share = _used_since(self.stepping_since)
                log.info(
                    "from the first step shown: %.2f s of CPU in %.1f s (%.1f %% of a core)",
                    cpu, wall, share,
                )  # fmt: skip

    # ------------------------------------------------------------------ http

    async def index(self, request):
        """The page (``/``), never cached."""
        return FileResponse(str(STATIC / "index.html"), headers={"Cache-Control": "no-store"})

    async def frame_json(self, request):
        """The newest frame, as a page that just connected would get it (for scripts)."""
        built = await asyncio.to_thread(self._build, [Page(ws=None)])
        return JSONResponse(json.loads(built[0][1][-1]))

    async def websocket(self, ws: WebSocket) -> None:
        """One page's websocket (``/ws``): frames go out through the pump; controls come in
        here, go to the source, and its reply goes back (``{"type": "reply", ...}``)."""
        await ws.accept()
        page = Page(ws)
        self.pages.add(page)
        await asyncio.to_thread(self.source.page_opened)
        try:
            while True:
                message = await ws.receive_json()
                if not isinstance(message, dict):
                    continue
                reply = await asyncio.to_thread(self.source.command, message)
                await page.send(page_json({"type": "reply", "cmd": message.get("cmd"), **reply}))
        except (WebSocketDisconnect, RuntimeError, ValueError):
            pass
        finally:
            self.pages.discard(page)

    # ------------------------------------------------------------------ frames

    async def pump(self) -> None:
        """Tick the source and send each free page its frame, ``fps`` times a second."""
        next_at = time.monotonic()
        while True:
            ready = []
            for page in list(self.pages):
                if page.busy:
                    page.dropped += 1
                else:
                    ready.append(page)
            try:  # in this thread: ~1 ms a frame, where a worker's hand-over and the loop's
                # wake-up on its result cost as much CPU again (docs/measurements/dashboard-cost.md)
                frames = self._build(ready)
            except Exception:
                log.exception("a frame failed")
                frames = []
            for page, texts in frames:
                page.busy = True
                asyncio.create_task(self._send(page, texts))
            next_at += self.interval_s
            delay = next_at - time.monotonic()
            if delay < -self.interval_s:  # behind by more than a frame: do not catch up
                next_at, delay = time.monotonic(), 0.0
            await asyncio.sleep(max(delay, 0.0))

    def _build(self, pages: list[Page]) -> list[tuple[Page, list[str]]]:
        """Tick the source, then each page's messages as JSON: the scene when it is new to
        the page, and its frame."""
        state = self.state
        out = []
        with state.lock:
            self.source.tick()
            self.ticks += 1
            if self.stepping_since is None and state.step >= 0:
                self.stepping_since = (time.monotonic(), time.process_time())
            for page in pages:
                parts = []
                if page.reader.scene_version != state.scene_version:
                    page.reader.scene_version = state.scene_version
                    parts.append(page_json({"type": "scene", "scene": state.scene}))
                frame = state.frame(page.reader)
                frame["server"] = {
                    "wall_ms": time.time() * 1e3,
                    "cpu_s": time.process_time(),
                    "sent": page.sent,
                    "dropped": page.dropped,
                }
                parts.append(page_json(frame))
                out.append((page, parts))
        return out

    async def _send(self, page: Page, texts: list[str]) -> None:
        try:
            for text in texts:
                await page.send(text)
            page.sent += 1
        except Exception:  # the page went away: its websocket task removes it
            self.pages.discard(page)
        finally:
            page.busy = False


def _used_since(since: tuple[float, float]) -> tuple[float, float, float]:
    """Wall seconds, CPU seconds of this process, and its share of a core (%) since
    ``since`` = ``(time.monotonic(), time.process_time())``."""
    wall, cpu = time.monotonic() - since[0], time.process_time() - since[1]
    return wall, cpu, 100 * cpu / max(wall, 1e-9)


def _json_default(obj):
    if hasattr(obj, "tolist"):  # numpy arrays and scalars
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


# msgspec's JSON: a frame's ~60 kB in a sixth of the standard library's time (NaN and
# infinities become null, which is what JSON.parse can read)
_encode_json = msgspec.json.Encoder(enc_hook=_json_default).encode


def page_json(message: dict) -> str:
    """A page's message as JSON text."""
    return _encode_json(message).decode()


def bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host:port``, inheritable by a child process.

    Parameters
    ----------
    host : str
        An address of this machine's, or a name for one (IPv6 when it holds a ``:``).
    port : int
        0: a free port.

    Raises
    ------
    ServeError
        The address cannot be bound (the port taken, the host not this machine's).
    """
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        bad_address = isinstance(exc, socket.gaierror) or exc.errno == errno.EADDRNOTAVAIL
        hint = (
            "another dashboard? choose another with --port or dashboard.port"
            if exc.errno == errno.EADDRINUSE
            else "an address of this machine's? choose one with --host or dashboard.host"
            if bad_address
            else "see --host and --port"
        )
        raise ServeError(
            f"cannot serve the dashboard on {host}:{port}: {exc.strerror or exc} ({hint})",
            bad_address=bad_address,
        ) from None
    sock.listen(64)
    sock.set_inheritable(True)
    return sock


def url_of(sock: socket.socket) -> str:
    """The page's address for a socket from `bind` (a wildcard host shown as 127.0.0.1)."""
    host, port = sock.getsockname()[:2]
    shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    if ":" in shown:  # an IPv6 address, bracketed in a URL
        shown = f"[{shown}]"
    return f"http://{shown}:{port}/"


def serve(
    source: Source,
    state: FrameState,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    fps: float = 30.0,
    on_ready: Callable[[str], None] = lambda url: None,
) -> None:
    """Serve the dashboard until SIGINT/SIGTERM (blocks).

    Called from the main thread, the signal ends it quietly, so the command's status is 0.

    Parameters
    ----------
    source : Source
        What feeds ``state``.
    state : FrameState
    host : str
        Address to listen on.
    port : int
        0: a free port.
    fps : float
        Frames a second to each page, > 0.
    on_ready : callable
        Called with the page's URL once the socket listens, before serving.

    Raises
    ------
    ValueError
        ``fps`` is not a finite number > 0.
    ServeError
        The address cannot be bound.
    """
    if not (isinstance(fps, int | float) and math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be > 0, got {fps!r}")
    sock = bind(host, port)
    dashboard = Dashboard(source, state, fps)
    # No permessage-deflate: a frame is mostly base64 of float32/uint32 arrays, which barely
    # compresses, and deflating it cost ~1 ms a frame (at 30 frames/s the largest share of
    # the dashboard's CPU in a lockstep run, by a yappi profile;
    # docs/measurements/dashboard-cost.md).
    config = uvicorn.Config(
        dashboard.app,
        log_level="warning",
        lifespan="on",
        ws_ping_interval=20.0,
        ws_per_message_deflate=False,
    )
    server = uvicorn.Server(config)
    on_ready(url_of(sock))
    # uvicorn shuts down on SIGINT/SIGTERM, then raises the signal again for the handler it
    # found: a quiet one here, so that the command ends with status 0 (the project's rule).
    quiet = threading.current_thread() is threading.main_thread()
    previous = {sig: signal.signal(sig, _ignore) for sig in _SIGNALS} if quiet else {}
    try:
        server.run(sockets=[sock])
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        sock.close()


_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _ignore(signum, frame) -> None:
    pass
