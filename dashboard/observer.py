"""The live source: an observer on the bus that feeds a :class:`~dashboard.state.FrameState`.

It joins the hub's router as a client, like an endpoint, but only subscribes and queries —
it never puts a loop message. It does not subscribe to the loop's own keys either: the
router would then send it four messages a step with the loop's congestion control, which
costs a lockstep loop far more than its 5 % budget and lets a slow observer hold the loop up
(docs/dashboard.md). Nor does it subscribe to the hub's telemetry: it *asks* for it, one
question at a time, and :meth:`BusObserver.tick` takes what the answers brought, a frame
at a time — so a dashboard that stops reading (frozen, swapped out, on a slow link) stops
the hub's sending too, where a subscriber's full socket held the hub's puts, and with
them the loop (docs/dashboard.md, "A frozen dashboard"):

- ``hub/view/*`` (:class:`~hub.protocol.HubView`, built ``loop.view_hz`` times a second;
  :class:`hub.shelf.Asker`): every spike and pulse since the last view, the body's
  trail, its newest reading and the newest motor command — what the loop carried,
  relayed by the hub;
- ``hub/status`` (subscribed, ``loop.status_hz`` times a second, a few hundred bytes, held
  by Zenoh in a ring; a full ring drops its oldest): the hub's state, counters and recent
  network bursts — and the final one, sent as the hub ends;
- liveliness ``alive/**`` (subscribed: a few samples a run): whether the hub is there.

It asks for views once it has tried to read the run's scene: a hub that waits for its
dashboard (``neuvision run --dashboard``) starts its steps then.

Each message is checked against the contract; a bad one is counted and left out.

A thread of its own asks the hub for the run's config (``hub/control`` ``config``: the world,
the period) and each endpoint for its description (the geometry, then every second its
counters), so no frame waits for a query. A new run (another run id on the wire) starts the
histories again and the scene is asked for anew. Controls go to ``hub/control``
(:func:`hub.ctl.request`).

With ``bus.security`` on it takes part as an ``operator`` when ``bus.certs_dir`` holds that
role's certificate ("mtls") or password ("password"), else as an ``observer``, which may
watch but not send controls nor ask for the config: the dashboard's own experiment file
then stands in for it.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable

import zenoh

from hub import security, wire
from hub.bus import BusError, open_session
from hub.config import BusSection
from hub.ctl import request
from hub.protocol import CONTROL_COMMANDS, Description, HubStatus, HubView, ProtocolError
from hub.shelf import Asker

from .scene import build_scene, world_for
from .state import FrameState

log = logging.getLogger(__name__)

STATUS_RING = 16  # statuses held between two frames (a full ring drops its oldest)
ENDPOINTS_EVERY_S = 1.0  # each endpoint's counters asked this often
RETRY_S = 1.0  # between tries to reach the hub, or its scene
QUERY_TIMEOUT_S = 2.0
# The hub sends its status loop.status_hz times a second while it lives: this many of its
# periods (and at least SILENT_MIN_S) without one, from a hub whose token is still there,
# and the link to it is taken for stuck, and joined again
SILENT_PERIODS = 3
SILENT_MIN_S = 3.0
TICKING_S = 1.0  # ... counted only while frames are taken (:meth:`BusObserver.tick`)
COMMANDS = tuple(c for c in CONTROL_COMMANDS if c != "config")


class BusObserver:
    """The dashboard's live source: watches the hub on the bus and feeds a `FrameState`.

    Nothing is joined before `start`; a thread of its own then tries, and tries again, to
    reach the hub.

    Parameters
    ----------
    bus : BusSection
        The experiment's ``[bus]`` section: the session, and where the hub listens or
        ``bus.connect``.
    state : FrameState
        What the page shows; fed under its lock.
    config : dict or None
        A plain config dict (the dashboard's own experiment file), standing in for the
        hub's when the hub does not give it.
    find_hub : callable or None
        Given when no address was: where the session's hub on this machine listens now
        (its locators), or None. Asked while no hub is there, so that the dashboard
        follows ``neuvision run`` from run to run (each run's hub on a port of its own).
    """

    def __init__(
        self,
        bus: BusSection,
        state: FrameState,
        config: dict | None = None,
        find_hub: Callable[[], tuple[str, ...] | None] | None = None,
    ):
        # The run's own transport (``bus.low_latency``, as the loop's links). Over Zenoh's
        # queued transport the hub's link to a dashboard beside a lockstep closed loop got
        # stuck, in 10 of 15 runs within 2.5-35 s: every *drop* message to it (the status, the
        # answers for views) dropped from then on while the link stayed up, and the page
        # froze on one step as the run went on (docs/dashboard.md, "A page that froze").
        # A frozen dashboard cannot hold the hub up over either: the views are asked for,
        # one question at a time (docs/dashboard.md, "A frozen dashboard").
        self.bus = dataclasses.replace(bus, connect_timeout_s=QUERY_TIMEOUT_S)
        self.config = config
        self.role = _role(bus)
        self.keys = bus.keys
        self.state = state
        self.where = ", ".join(bus.connect or bus.listen)
        self.session: zenoh.Session | None = None
        self._status = None  # the subscriber to hub/status, once connected
        self._status_inbox = wire.Inbox()
        self._views: Asker | None = None
        self._declared: list = []
        self.run: str | None = None  # the run id seen on the wire
        self._hub_config: dict | None = None  # the present hub's config, once asked
        self._world = None  # ... and its world
        self.ids: dict[str, str] | None = None  # role -> id, from the run's config
        self.dropped: Counter[str] = Counter()
        self._hub_alive = False
        self._need_scene = threading.Event()
        self._need_scene.set()
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="dashboard-watch", daemon=True)
        state.source = {
            "kind": "live",
            "session": bus.session,
            "hub": self.where,
            "controls": self.role == "operator",
        }
        state.observer = {"connected": False, "hub_alive": False, "dropped": {}}
        self.tries = 0  # tries at reaching the hub
        self.rejoins = 0  # links to a live hub that went silent, joined again
        self._rejoining = False  # until the hub's token is seen on the new link
        self._heard_at = 0.0  # time.monotonic() of the hub's last status or view taken
        self._ticked_at = 0.0  # ... and of the last tick, which takes them
        self._why: str | None = None  # why the last try failed, as said
        self._find_hub = find_hub
        self._next_look = 0.0  # when to ask find_hub again

    # ------------------------------------------------------------------ life

    def start(self) -> None:
        """Start the watch thread, which joins the bus and asks the hub (returns at once)."""
        self._thread.start()

    def page_opened(self) -> None:
        """A page connected (nothing to do: the bus goes on regardless)."""

    def close(self) -> None:
        """Stop the watch thread (waiting up to 5 s) and leave the bus."""
        self._closed.set()
        self._thread.join(timeout=5)
        if self.session is not None:
            self.session.close()
            self.session = None

    # ------------------------------------------------------------------ frames

    def tick(self) -> None:
        """Take what the answers brought since the last tick into the state, and ask again
        where answered (caller holds the state's lock)."""
        if self._status is None:
            return
        self._ticked_at = time.monotonic()
        while (sample := self._status.try_recv()) is not None:
            try:
                raw = self._status_inbox.feed(sample.payload, sample.attachment)
            except wire.WireError as exc:
                self.dropped[exc.kind] += 1
                continue
            if raw is not None:
                self._heard_at = time.monotonic()
                self._take("status", raw)
        for raw in self._views.take() if self._views is not None else ():
            self._heard_at = time.monotonic()
            self._take("view", raw)
        dropped = self.dropped + (self._views.dropped if self._views is not None else Counter())
        self.state.observer = {
            "connected": True,
            "hub_alive": self._hub_alive,
            "dropped": dict(dropped),
            "rejoins": self.rejoins,
        }

    def _take(self, name: str, raw: bytes) -> None:
        try:
            self._handle(name, raw)
        except ProtocolError as exc:
            if not self.dropped[exc.kind]:
                log.warning("dropped a message on hub/%s (%s): %s", name, exc.kind, exc)
            self.dropped[exc.kind] += 1

    def _handle(self, name: str, raw: bytes) -> None:
        state = self.state
        if name == "status":
            status = HubStatus.decode(raw).to_dict()
            extra = status.get("extra") or {}
            self._new_run(extra.get("run"))
            state.set_status(status)
            state.add_bursts(extra.get("recent_network_bursts") or [])
            return
        v = HubView.decode(raw)
        self._new_run(v.run)
        state.add_spikes(v.spike_channel, v.spike_t_ms, v.from_s * 1e3, v.to_s * 1e3)
        if v.pulse_channel.size:
            state.add_pulses(v.pulse_channel, v.pulse_t_ms)
        if v.trail_m.size:
            state.add_trail(v.trail_m.reshape(-1, 2))
        if v.pose is not None:
            state.add_sensors(v.sensors_step, v.to_s, v.pose, v.ranges_m, v.contact, trail=False)
        if v.left_mps is not None:
            state.add_motor(v.step, v.left_mps, v.right_mps)

    def _new_run(self, run: str | None) -> None:
        """A message of ``run``: a run other than the last one seen starts the page afresh
        with its own scene. The first run seen keeps the scene read, or being read, since
        its hub came (read again, it would empty the histories of the steps shown
        meanwhile: a status that came while the scene was read lost the run's first
        spikes)."""
        if run and run != self.run:
            first, self.run = self.run is None, run
            if first:
                return
            self.state.reset()
            self._need_scene.set()

    # ------------------------------------------------------------------ controls

    def command(self, message: dict) -> dict:
        """A control from the page, ``{"cmd": "pause" | "resume" | "stop" | "status"}``,
        sent to the hub; its reply as ``{ok, state, reason}``."""
        cmd = message.get("cmd")
        if cmd not in COMMANDS:
            return {"ok": False, "state": "", "reason": f"unknown command {cmd!r}"}
        if self.role != "operator":
            return {"ok": False, "state": "", "reason": "read-only: an observer's certificate"}
        if self.session is None:
            return {"ok": False, "state": "", "reason": f"no hub reached at {self.where}"}
        reply = request(self.session, self.keys, cmd, timeout_s=QUERY_TIMEOUT_S)
        if reply is None:
            return {"ok": False, "state": "", "reason": "no hub answered"}
        return {"ok": reply.ok, "state": reply.state, "reason": reply.reason}

    # ------------------------------------------------------------------ the watch thread

    def _watch(self) -> None:
        next_counters = 0.0
        while not self._closed.is_set():
            if not self._hub_alive and self._follow():
                continue
            if self.session is None and not self._connect():
                self._closed.wait(RETRY_S)
                continue
            if self._silent():
                self._rejoin()
                continue
            if self._need_scene.is_set() and self._hub_alive:
                self._need_scene.clear()
                if not self._fetch_scene():
                    self._need_scene.set()
                self._watch_views()
            now = time.monotonic()
            if now >= next_counters and self.ids:
                next_counters = now + ENDPOINTS_EVERY_S
                self._fetch_counters()
            self._closed.wait(0.1 if self._need_scene.is_set() else 0.25)

    def _silent(self) -> bool:
        """Whether a live hub's link to this dashboard has been silent too long: neither a
        status nor a view for SILENT_PERIODS of the hub's status period. Zenoh once kept
        such a link up while dropping everything the hub sent on it (docs/dashboard.md, "A
        page that froze")."""
        now = time.monotonic()
        if not self._hub_alive or now - self._ticked_at > TICKING_S:  # nothing taken: no news
            return False
        status_hz = ((self._hub_config or self.config or {}).get("loop") or {}).get("status_hz")
        limit_s = max(SILENT_MIN_S, SILENT_PERIODS / status_hz if status_hz else 0.0)
        return now - self._heard_at > limit_s

    def _rejoin(self) -> None:
        """Leave the bus and join it again: a new link to the hub. The views are asked for
        after the last one taken, as before (a gap if the hub no longer keeps those)."""
        self.rejoins += 1
        log.log(
            logging.WARNING if self.rejoins == 1 else logging.INFO,
            "nothing from the hub at %s for %.1f s while it is there: joining again (%d time(s))",
            self.where, time.monotonic() - self._heard_at, self.rejoins,
        )  # fmt: skip
        # the hub seen on the new link is taken for the same one (a new run shows itself
        # by its run id, _new_run); one gone meanwhile is seen gone
        self._hub_alive, self._rejoining = False, True
        with self.state.lock:
            session, self.session, self._status = self.session, None, None
            views, self._views = self._views, None
        self._declared = []
        session.close()
        if not self._connect():  # the hub went meanwhile: the next one is a hub anew
            self._rejoining = False
        elif views is not None:
            asker = Asker(self.session, self.keys.hub_view)
            asker.mark = views.mark
            with self.state.lock:
                self._views = asker

    def _follow(self) -> bool:
        """With no hub there, whether the session's hub on this machine now listens
        elsewhere (a new ``neuvision run``): if so, the link goes there, and the page
        starts afresh with that run (True)."""
        now = time.monotonic()
        if self._find_hub is None or now < self._next_look:
            return False
        self._next_look = now + RETRY_S
        locators = self._find_hub()
        if not locators or tuple(locators) == tuple(self.bus.connect or self.bus.listen):
            return False  # none, or the one already tried
        self.bus = dataclasses.replace(self.bus, connect=tuple(locators))
        self.where = ", ".join(self.bus.connect)
        log.info("the hub of session %r listens on %s now: following it", self.bus.session,
                 self.where)  # fmt: skip
        with self.state.lock:
            session, self.session, self._status, self._views = self.session, None, None, None
            self.state.source = {**self.state.source, "hub": self.where}
        self._declared = []
        if session is not None:
            session.close()
        self._hub_config, self._rejoining = None, False
        self._need_scene.set()
        return True

    def _connect(self) -> bool:
        try:
            session = open_session(
                self.bus, listener=False, role=self.role, timeout_name="one try of many"
            )
        except BusError as exc:
            # a hub not started yet, or one that refuses this dashboard's certificate or
            # password, or none of its own: said in the terminal (once per reason) and on
            # the page, not only at debug level
            self.tries += 1
            why = str(exc)
            if why != self._why:
                self._why = why
                log.info("waiting for a hub at %s (session %r): %s", self.where,
                            self.bus.session, why)  # fmt: skip
            with self.state.lock:
                self.state.observer = {**self.state.observer, "reason": why}
            return False
        ring = zenoh.handlers.RingChannel(STATUS_RING)
        status = session.declare_subscriber(self.keys.hub_status, ring)
        self._declared = [
            session.liveliness().declare_subscriber(
                self.keys.alive_all, self._on_alive, history=True
            )
        ]
        with self.state.lock:
            self.session, self._status = session, status
            self._heard_at = time.monotonic()  # the silence counts from the link's start
        log.info("observing session %r at %s", self.bus.session, self.where)
        return True

    def _watch_views(self) -> None:
        """Start asking for views (once), after the first try at the scene: a hub that
        waits for its dashboard (``neuvision run --dashboard``) starts its steps when it is
        first asked, and by then the world is read (a first read compiles or loads the
        geometry kernels: seconds of CPU on a slow machine, better spent before the steps
        than during them)."""
        if self._views is None:
            views = Asker(self.session, self.keys.hub_view)
            with self.state.lock:
                self._views = views

    def _on_alive(self, sample) -> None:
        if self.keys.parse_alive(str(sample.key_expr)) == ("hub", "0"):
            alive = sample.kind == zenoh.SampleKind.PUT
            if alive and not self._hub_alive and not self._rejoining:
                self._hub_config = None  # a hub (again): its run's config and endpoints
                self._need_scene.set()
            self._hub_alive, self._rejoining = alive, False

    def _fetch_scene(self) -> bool:
        """Ask the hub for the run's config (once per hub: the hub records each control
        query; the world is read at once, most often before the run's steps begin), then
        each endpoint for its description."""
        if self._hub_config is None:
            config = None
            if self.role == "operator":
                reply = request(self.session, self.keys, "config", timeout_s=QUERY_TIMEOUT_S)
                config = reply.data if reply is not None else None
            self._hub_config = config or self.config or {}
            self._world = world_for(self._hub_config)
        config = self._hub_config
        ids = {role: str((config.get(role) or {}).get("id", "0")) for role in ("body", "culture")}
        descriptions = {}
        for role, i in ids.items():
            for raw in wire.get(
                self.session, self.keys.describe(role, i), timeout_s=QUERY_TIMEOUT_S
            ):
                try:
                    descriptions[role] = Description.decode(raw)
                except ProtocolError as exc:
                    log.warning("%s/%s described itself badly: %s", role, i, exc)
        if len(descriptions) < 2:
            return False
        scene = build_scene(descriptions, config, self._world)
        with self.state.lock:
            self.ids = ids
            self.state.set_scene(scene)
        return True

    def _fetch_counters(self) -> None:
        """Each endpoint's counters, asked; one that does not answer keeps what was last
        known of it (its kind, its last counters), marked not answering."""
        endpoints = {}
        for role, i in self.ids.items():
            replies = wire.get(self.session, self.keys.describe(role, i), timeout_s=1.0)
            known = self.state.endpoints.get(role) or {}
            last = {
                k: known[k] for k in ("kind", "counters") if k in known and known.get("id") == i
            }
            entry = {"id": i, "alive": bool(replies), **({} if replies else last)}
            for raw in replies:
                try:
                    desc = Description.decode(raw)
                except ProtocolError:
                    continue
                entry.update(kind=desc.kind, counters=_plain(desc.counters or {}))
            endpoints[role] = entry
        with self.state.lock:
            self.state.set_endpoints(endpoints)


def _role(bus: BusSection) -> str:
    """``operator`` (watch and control), or ``observer`` (watch only) when the security
    profile is on and ``bus.certs_dir`` holds no operator's certificate."""
    if bus.security == "none":
        return "operator"
    if bus.security == "password":
        return (
            "operator"
            if security.password_file(bus.certs_dir, "operator").is_file()
            else "observer"
        )
    files = security.certificate_files(bus.certs_dir, "operator")
    return "operator" if all(path.is_file() for path in files.values()) else "observer"


def _plain(value):
    """A counters map made JSON-ready (bytes left out)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items() if not isinstance(v, bytes)}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value if not isinstance(v, bytes)]
    return value
