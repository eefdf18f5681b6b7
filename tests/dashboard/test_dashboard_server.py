"""The dashboard's web server: the page, its assets, frames and controls on a websocket."""

from __future__ import annotations

import json
import threading
import time
import urllib.request
from contextlib import contextmanager

import pytest
import uvicorn
from websockets.sync.client import connect

from dashboard.replay import ReplaySource
from dashboard.server import Dashboard, ServeError, bind, url_of
from dashboard.state import FrameState
from tests.dashboard.synthetic import pose, write_run


@contextmanager
def serving(source, state, fps=30.0):
    """The dashboard's app on a free loopback port, in a thread; its URL."""
    sock = bind("127.0.0.1", 0)
    app = Dashboard(source, state, fps).app
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", lifespan="on"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        assert time.monotonic() < deadline, "the server did not start"
        time.sleep(0.01)
    try:
        yield url_of(sock)
    finally:
        server.should_exit = True
        thread.join(timeout=10)
        sock.close()


def _next(ws, kind, timeout_s=10.0, where=lambda m: True):
    """The next message of type ``kind`` that satisfies ``where``."""
    deadline = time.monotonic() + timeout_s
    while True:
        message = json.loads(ws.recv(timeout=max(deadline - time.monotonic(), 0.01)))
        if message["type"] == kind and where(message):
            return message


@pytest.fixture
def replay(tmp_path):
    write_run(tmp_path / "run")
    state = FrameState()
    return ReplaySource(tmp_path / "run", state, speed=2.0), state


def test_the_page_and_its_assets_are_served_from_the_package(replay):
    with serving(*replay) as url:
        page = urllib.request.urlopen(url, timeout=10).read().decode()
        assert "/static/dashboard.js" in page and "<canvas" in page
        script = urllib.request.urlopen(url + "static/dashboard.js", timeout=10).read().decode()
        assert "new WebSocket" in script
        frame = json.loads(urllib.request.urlopen(url + "frame", timeout=10).read())
        assert frame["type"] == "frame" and frame["source"]["kind"] == "replay"


def test_a_page_gets_the_scene_then_frames_and_its_controls_are_answered(replay):
    with serving(*replay) as url, connect(url.replace("http", "ws") + "ws") as ws:
        scene = _next(ws, "scene")["scene"]
        assert scene["culture"]["channel"] == [0, 1, 2, 3] and len(scene["obstacles"]) == 3
        first = _next(ws, "frame")
        assert first["reset"]
        later = _next(ws, "frame", where=lambda f: f["t_s"] > first["t_s"] + 0.1)
        assert not later["reset"] and later["replay"]["playing"]
        ws.send(json.dumps({"cmd": "seek", "t_s": 1.0}))
        reply = _next(ws, "reply")
        assert reply["ok"] and reply["cmd"] == "seek"
        jumped = _next(ws, "frame", where=lambda f: f["reset"])
        assert jumped["step"] >= 99 and jumped["pose"][0] >= pose(99)[0]
        ws.send(json.dumps({"cmd": "stop"}))
        refused = _next(ws, "reply")
        assert not refused["ok"] and "cannot" in refused["reason"]


def test_a_port_taken_is_one_clear_error():
    sock = bind("127.0.0.1", 0)
    try:
        with pytest.raises(
            ServeError, match=r"cannot serve the dashboard on 127.0.0.1.*another"
        ) as e:
            bind("127.0.0.1", sock.getsockname()[1])
        assert not e.value.bad_address  # the machine's state, not the address given
    finally:
        sock.close()


def test_a_host_that_is_not_this_machines_is_said_so():
    # TEST-NET-1 (RFC 5737): never a local address; bind() refuses it at once, sends nothing
    with pytest.raises(
        ServeError, match=r"an address of this machine's\? choose one with --host"
    ) as e:
        bind("192.0.2.1", 0)
    assert e.value.bad_address


@pytest.mark.parametrize("host, shown", [("127.0.0.1", "127.0.0.1"), ("::1", "[::1]")])
def test_the_pages_address_is_one_a_browser_opens(host, shown):
    sock = bind(host, 0)
    try:
        assert url_of(sock) == f"http://{shown}:{sock.getsockname()[1]}/"
    finally:
        sock.close()
