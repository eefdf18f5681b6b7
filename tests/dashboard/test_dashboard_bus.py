"""The dashboard's observer on a real bus: a hub in this process, test endpoints as
processes; what it shows, its controls, and `neuvision ctl`."""

from __future__ import annotations

import json
import logging
import threading
import time

import pytest

from dashboard.observer import BusObserver
from dashboard.state import FrameState, Reader
from hub.cli import main
from hub.config import load_config
from hub.protocol import HubStatus, SpikeBatch
from tests.harness import harness, wait_for

pytestmark = pytest.mark.bus


def test_the_observer_shows_the_run_and_pauses_resumes_and_stops_it(
    tmp_path, bus_overrides, capsys
):
    out: dict = {}
    with harness(
        tmp_path,
        bus_overrides,
        "loop.mode=realtime",
        "experiment.duration_s=100",
        "loop.status_hz=20",
    ) as h:
        state = FrameState()
        observer = BusObserver(h.cfg.bus, state)
        reader = Reader()
        port = h.cfg.bus.listen[0].rsplit(":", 1)[1]
        ctl = ["--connect", f"127.0.0.1:{port}", "--session", h.cfg.bus.session]

        def frame(page: Reader = reader) -> dict:
            with state.lock:
                observer.tick()
                return state.frame(page)

        def operator():
            observer.start()
            try:
                wait_for(lambda: frame()["step"] >= 30 and len(state.tapes["rates"]) >= 3, 30)
                culture = lambda: frame()["endpoints"].get("culture", {})  # noqa: E731
                wait_for(lambda: culture().get("counters", {}).get("steps", 0) > 0, 10)
                out["frame"], out["scene"] = frame(Reader()), state.scene  # all that is kept
                out["pause"] = observer.command({"cmd": "pause"})
                wait_for(lambda: frame()["status"]["state"] == "paused")
                paused_at = frame()["status"]["step"]
                n = state.status["wall_s"]
                wait_for(lambda: frame()["status"]["wall_s"] > n + 0.25)  # statuses go on
                out["paused_steps"] = (paused_at, frame()["status"]["step"])
                out["ctl_status"] = main(["ctl", "status", *ctl])
                out["ctl_resume"] = main(["ctl", "resume", *ctl])
                wait_for(lambda: frame()["status"]["step"] > paused_at + 10)
                out["stop"] = observer.command({"cmd": "stop"})
                wait_for(lambda: frame()["status"]["state"] == "stopped", 10)
                out["ended"] = frame()["status"]["extra"]
                out["bad"] = observer.command({"cmd": "config"})
            finally:
                observer.close()

        thread = threading.Thread(target=operator)
        thread.start()
        result = h.run()
        thread.join(timeout=60)
    f, scene = out["frame"], out["scene"]
    # the scene: the endpoints' descriptions, the run's config
    assert (
        scene["culture"]["channel"] == [0, 1, 2, 3] and len(scene["body"]["sensor_angles_rad"]) == 3
    )
    assert (scene["mode"], scene["period_ms"]) == ("realtime", 10.0)
    # the newest reading: the echo body's pose is (step, wheels of its command)
    assert f["pose"][0] == f["step"] and len(f["ranges"]) == 3
    assert f["spikes"]["n"] > 0 and f["pulses"]["n"] > 0 and f["rates"]
    assert f["status"]["extra"]["run"] == h.hub.run_id and f["status"]["mode"] == "realtime"
    assert f["endpoints"]["culture"]["alive"] and f["endpoints"]["culture"]["counters"]["steps"] > 0
    assert f["source"] == {
        "kind": "live",
        "session": h.cfg.bus.session,
        "hub": h.cfg.bus.listen[0],
        "controls": True,
    }
    # the controls
    assert out["pause"] == {"ok": True, "state": "paused", "reason": ""}
    first, later = out["paused_steps"]
    assert later <= first + 1  # nothing advanced while paused (the step in flight may end)
    assert out["ctl_status"] == 0 and out["ctl_resume"] == 0
    printed, text = [], capsys.readouterr().out.strip()
    while text:  # the JSON objects ctl printed, one after the other
        obj, end = json.JSONDecoder().raw_decode(text)
        printed.append(obj)
        text = text[end:].strip()
    assert [(p["ok"], p["state"]) for p in printed] == [(True, "paused"), (True, "running")]
    assert out["stop"]["ok"] and not out["bad"]["ok"]
    assert result.outcome == "stopped"
    # the final status says how the run ended (a page showed "stopped" for a fault too)
    assert (out["ended"]["outcome"], out["ended"]["reason"]) == ("stopped", "stopped by control")
    # an observer: it asked the hub for the config once, and put nothing on the loop's keys
    commands = [e.payload["cmd"] for e in h.record.events if e.key == "control"]
    assert commands == ["config", "pause", "status", "resume", "stop"]
    assert result.counts["dropped"] == {}


def test_a_hub_that_waits_for_its_dashboard_steps_once_the_dashboard_has_the_scene(
    tmp_path, bus_overrides
):
    """``neuvision run --dashboard``: the first step waits until the dashboard watches, which
    it does once it has read the run's scene; the page then has the run from its start."""
    with harness(tmp_path, bus_overrides, "loop.mode=realtime", "experiment.duration_s=1") as h:
        state = FrameState()
        observer = BusObserver(h.cfg.bus, state)
        scene_at_first_view: list = []
        done = threading.Event()

        hub_waits = threading.Event()  # the hub said it waits for the dashboard

        class Said(logging.Handler):
            def emit(self, record):
                if record.getMessage().startswith("waiting for the dashboard"):
                    hub_waits.set()

        said, hub_log = Said(), logging.getLogger("hub.loop")
        hub_log.addHandler(said)
        level = hub_log.level
        hub_log.setLevel(logging.INFO)

        def page():
            hub_waits.wait(30)
            time.sleep(0.5)  # the dashboard comes half a second after the hub waits for it
            observer.start()
            while not done.is_set():
                with state.lock:
                    observer.tick()
                    if state.step >= 0 and not scene_at_first_view:
                        scene_at_first_view.append(state.scene)
                time.sleep(0.005)

        thread = threading.Thread(target=page)
        thread.start()
        try:
            result = h.run(wait_for_view_s=30)
        finally:
            done.set()
            thread.join(timeout=10)
            observer.close()
            hub_log.removeHandler(said)
            hub_log.setLevel(level)
    (wait,) = [e.payload for e in h.record.events if e.key == "view_wait"]
    assert wait["watched"] and wait["waited_s"] > 0.25  # it did wait
    assert result.outcome == "completed" and scene_at_first_view[0]["culture"] is not None
    # the page has the run from its start: its first spike is the run's first
    shown_ms = min(float(t.min()) for t, _ in state.tapes["spikes"].since(0))
    batches = [b for _, b in sorted(h.received(SpikeBatch).items()) if b.channel.size]
    assert shown_ms == batches[0].t0_s * 1e3 + float(batches[0].t_ms[0])


def test_a_hub_that_waits_for_a_dashboard_that_never_comes_starts_after_its_wait(
    tmp_path, bus_overrides
):
    with harness(tmp_path, bus_overrides, "experiment.duration_s=0.1") as h:
        result = h.run(wait_for_view_s=0.5)
    (wait,) = [e.payload for e in h.record.events if e.key == "view_wait"]
    assert not wait["watched"] and wait["waited_s"] == 0.5
    assert result.outcome == "completed" and result.steps == 10


def test_neuvision_ctl_says_when_no_hub_answers(capsys):
    from hub.bus import free_tcp_port

    code = main(["ctl", "status", "--connect", f"127.0.0.1:{free_tcp_port()}", "--timeout-s", "1"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("neuvision: cannot reach the hub at tcp/127.0.0.1:")
    # the wait is ctl's own option, not the config key (setting that changes nothing)
    assert "within 1 s (--timeout-s)" in err[-1] and "connect_timeout_s" not in err[-1]


def test_views_larger_than_one_put_reach_the_observer_whole(tmp_path, bus_overrides):
    """A culture firing 20,000 spikes a step: each view (~240 kB) goes in frames."""
    seen: dict = {}
    with harness(
        tmp_path,
        bus_overrides,
        'culture.kind="tests.endpoints:LargeCulture"',
        "culture.params={n_channels=4096, spikes_per_step=20000}",
        "online.enabled=false",
        "loop.mode=realtime",
        "loop.period_ms=50",
        "experiment.duration_s=60",
    ) as h:
        state = FrameState()
        observer = BusObserver(h.cfg.bus, state)

        def held() -> int:
            """Spikes the state holds for the raster."""
            with state.lock:
                observer.tick()
                return sum(t.size for t, _ in state.tapes["spikes"].since(0))

        def operator():
            observer.start()
            try:
                wait_for(lambda: held() >= 3 * 20000, 60)
                seen["spikes"] = held()
                seen["dropped"] = dict(observer.dropped)
                seen["stop"] = observer.command({"cmd": "stop"})
            finally:
                observer.close()

        thread = threading.Thread(target=operator)
        thread.start()
        result = h.run()
        thread.join(timeout=60)
    assert seen["spikes"] >= 60000 and seen["dropped"] == {} and seen["stop"]["ok"]
    assert result.outcome == "stopped"


def test_a_streamed_steps_spikes_reach_live_displays_and_the_decoder_whole(tmp_path, bus_overrides):
    """A culture that sends each step's spikes in a part and then its batch (contract v4):
    each view has the step's spikes merged and in time order (a display closes its rate
    bins up to the window's end), and the decoder counts all of them."""
    from hub.bus import open_session
    from hub.protocol import HubView, MotorCommand
    from hub.shelf import Asker

    views: list[HubView] = []
    with harness(
        tmp_path, bus_overrides, 'culture.kind="tests.endpoints:StreamingCulture"',
        "experiment.duration_s=0.5",
    ) as h:  # fmt: skip
        asking = threading.Event()

        def display():  # a live display: asks for views, 100 times a second
            session = open_session(h.cfg.bus, listener=False)  # once the hub listens
            asker = Asker(session, h.cfg.bus.keys.hub_view)
            while asking.is_set():
                views.extend(HubView.decode(raw) for raw in asker.take())
                time.sleep(0.01)
            session.close()

        asking.set()
        thread = threading.Thread(target=display)
        thread.start()
        try:
            result = h.run(wait_for_view_s=30)
            wait_for(lambda: views and views[-1].step == result.steps, 5.0)
        finally:
            asking.clear()
            thread.join(timeout=10)
    assert result.outcome == "completed" and result.counts["dropped"] == {}
    n = result.steps
    assert len(h.record.decoded(SpikeBatch, "part")) == n
    # the decoder had both: a step's spikes are its pulses' echoes and the part's one
    per_step = dict.fromkeys(range(n), 0)
    for batch in h.record.decoded(SpikeBatch, "rx", "part"):
        per_step[batch.step] += batch.channel.size
    # step k's command is decoded from step k-1's spikes (the first two start the
    # pipeline, step n is the final stop)
    motors = h.sent(MotorCommand)
    decoded = {int(motors[k].left_mps): motors[k].right_mps for k in range(2, n)}
    assert decoded == {k: float(per_step[k]) for k in range(1, n - 1)}
    assert min(decoded.values()) == 1 and max(decoded.values()) > 1
    channel = [c for v in views for c in v.spike_channel.tolist()]
    assert channel.count(1) == n and len(channel) == h.record.spikes()[0].size
    for v in views:  # each step whole: its echoes (at 0 ms) before the part's spike (9 ms)
        assert v.spike_t_ms.tolist() == sorted(v.spike_t_ms.tolist())


def test_a_dashboard_that_cannot_join_says_why(tmp_path, caplog):
    """`neuvision dashboard --connect` under mTLS with no certificate of its own, or a hub
    that refuses it, said nothing: the terminal stayed silent and the page said "waiting for
    a hub" for ever. Now the reason is logged (once per reason) and in the page's frames."""
    import logging

    from hub.bus import free_tcp_port
    from hub.config import BusSection

    (tmp_path / "ca.pem").write_text("")  # a folder without the observer's certificate
    bus = BusSection(
        session="test-nocert",
        listen=(f"tls/127.0.0.1:{free_tcp_port()}",),
        security="mtls",
        certs_dir=str(tmp_path),
    )
    state = FrameState()
    caplog.set_level(logging.INFO, logger="dashboard.observer")
    observer = BusObserver(bus, state)
    observer.start()
    try:
        wait_for(lambda: "reason" in state.observer, 10)
        assert "no certificate file" in state.observer["reason"]
        assert "observer.pem" in state.observer["reason"]
        assert not state.observer["connected"]
        wait_for(lambda: any("no certificate file" in r.getMessage() for r in caplog.records))
        tries = observer.tries
        wait_for(lambda: observer.tries >= tries + 2, 10)  # it goes on trying ...
    finally:
        observer.close()
    said = [r for r in caplog.records if "no certificate file" in r.getMessage()]
    assert len(said) == 1  # ... and says it once


@pytest.mark.parametrize("low_latency", [True, False])
def test_the_observer_joins_over_the_runs_own_transport(bus_overrides, low_latency):
    # over the queued transport beside a low-latency loop, the hub's link to a dashboard
    # got stuck dropping every status and view in most lockstep runs (docs/dashboard.md,
    # "A page that froze")
    from hub.config import load_config

    cfg = load_config(None, [*bus_overrides, f"bus.low_latency={str(low_latency).lower()}"])
    observer = BusObserver(cfg.bus, FrameState())
    assert observer.bus.low_latency is low_latency


def test_a_link_to_a_live_hub_that_goes_silent_is_joined_again(bus_overrides, caplog):
    """A hub whose token stays while nothing it sends arrives (Zenoh once kept such a link
    up, dropping all the hub sent on it: docs/dashboard.md, "A page that froze"): the
    observer leaves and joins again, and takes the hub's statuses once they come."""
    from hub.bus import open_session

    cfg = load_config(None, bus_overrides)
    keys = cfg.bus.keys
    hub = open_session(cfg.bus, listener=True)  # a stand-in hub: its token and its status
    token = hub.liveliness().declare_token(keys.hub_alive)  # noqa: F841
    publisher = hub.declare_publisher(keys.hub_status)
    state = FrameState()
    observer = BusObserver(cfg.bus, state, config={"loop": {"status_hz": 20.0}})
    sending = threading.Event()
    sending.set()
    stop = threading.Event()

    def send_statuses():
        step = 0
        while not stop.wait(0.05):
            if sending.is_set():
                step += 1
                status = HubStatus(
                    step=step, t_s=step / 100, mode="lockstep", state="running",
                    late={}, missing={}, dropped={}, alive=["body/0", "culture/0"],
                )  # fmt: skip
                publisher.put(status.encode())

    def taken_step() -> int:
        with state.lock:
            observer.tick()
            return state.status.get("step", 0)

    sender = threading.Thread(target=send_statuses, daemon=True)
    sender.start()
    caplog.set_level(logging.INFO, logger="dashboard.observer")
    observer.start()
    try:
        wait_for(lambda: taken_step() > 5, 10)
        sending.clear()  # the hub lives on; nothing of its reaches the observer
        silent_at = time.monotonic()
        wait_for(lambda: taken_step() >= 0 and observer.rejoins == 1, 10)
        waited_s = time.monotonic() - silent_at
        sending.set()
        before = taken_step()
        wait_for(lambda: taken_step() > before + 5, 10)
    finally:
        stop.set()
        sender.join(timeout=5)
        observer.close()
        hub.close()
    # silent for SILENT_MIN_S (3 s: 3 periods of the hub's 20 Hz status are less) before it
    # joins again, and only once: the statuses came again on the new link
    assert 3.0 <= waited_s < 6.0
    assert observer.rejoins == 1 and state.observer["rejoins"] == 1
    said = [r.getMessage() for r in caplog.records if "joining again" in r.getMessage()]
    assert len(said) == 1 and "while it is there" in said[0]


def test_the_observer_follows_the_sessions_next_hub_on_this_machine(tmp_path, bus_overrides):
    """`neuvision run` puts each run's hub on a port of its own: a dashboard given no
    address asks where the session's hub listens now (hub/local_hubs.py) while none is
    there, and goes on to the next run. It stayed on the first run's port for ever."""
    from hub.bus import free_tcp_port

    second = [
        *[o for o in bus_overrides if not o.startswith("bus.listen")],
        f'bus.listen=["tcp/127.0.0.1:{free_tcp_port()}"]',
    ]
    runs = ["loop.mode=realtime", "experiment.duration_s=1.5"]
    where: dict = {}
    state = FrameState()
    ticking = threading.Event()

    def tick() -> None:  # as the page's frames do
        while not ticking.wait(0.05):
            with state.lock:
                observer.tick()

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    with harness(tmp_path / "a", bus_overrides, *runs) as a:
        where["now"] = a.cfg.bus.listen
        observer = BusObserver(a.cfg.bus, state, find_hub=lambda: where.get("now"))
        observer.start()
        ticker = threading.Thread(target=tick)
        ticker.start()
        try:
            assert a.run().outcome == "completed"
            wait_for(lambda: observer.run == a.hub.run_id, 10)
            with harness(tmp_path / "b", second, *runs) as b:
                where["now"] = b.cfg.bus.listen  # as the run's hub file says
                assert b.run().outcome == "completed"
                wait_for(lambda: observer.run == b.hub.run_id, 20)
                assert state.source["hub"] == b.cfg.bus.listen[0]
        finally:
            ticking.set()
            ticker.join(5)
            observer.close()


def test_an_endpoint_that_stops_answering_keeps_what_was_known_of_it(monkeypatch):
    """Its panel lost its kind and counters and showed dashes once it stopped answering:
    what was last known stays, marked as not answering."""
    from hub.config import load_config

    state = FrameState()
    observer = BusObserver(load_config(None, []).bus, state)
    observer.ids = {"body": "0"}
    state.set_endpoints(
        {"body": {"id": "0", "alive": True, "kind": "sim_robot", "counters": {"steps": 57}}}
    )
    monkeypatch.setattr("dashboard.observer.wire.get", lambda *a, **k: [])  # no answer
    observer._fetch_counters()
    assert state.endpoints["body"] == {
        "id": "0",
        "alive": False,
        "kind": "sim_robot",
        "counters": {"steps": 57},
    }


def _status_of(run: str) -> bytes:
    return HubStatus(
        step=3, t_s=0.03, mode="realtime", state="running", late={}, missing={},
        dropped={}, alive=[], extra={"run": run},
    ).encode()  # fmt: skip


def test_the_first_run_seen_keeps_the_scene_read_since_its_hub_came_and_a_next_run_reads_its_own():
    """A status of the first run that came while its scene was being read asked for the
    scene again, and reading it emptied what the page had of the run's first steps."""
    state = FrameState()
    observer = BusObserver(load_config(None, []).bus, state)  # not started: no bus
    observer._need_scene.clear()  # as the watch thread does while it reads the scene
    observer._handle("status", _status_of("a1" * 16))
    assert not observer._need_scene.is_set()  # not read twice
    state.set_scene({"name": "t", "culture": {"channel": [0], "x_um": [0.0], "y_um": [0.0]}})
    state.add_spikes([0], [25.0], 0.0, 30.0)
    observer._handle("status", _status_of("a1" * 16))
    assert state.tapes["spikes"].since(0)  # the page keeps its spikes
    observer._handle("status", _status_of("b2" * 16))  # another run: its own scene
    assert observer._need_scene.is_set() and not state.tapes["spikes"].since(0)
