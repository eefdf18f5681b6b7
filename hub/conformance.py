"""Endpoint conformance suite: does a body or culture endpoint keep contract v2?

Any :class:`~hub.endpoint.Endpoint` subclass (a simulator, a device adapter, another
backend) can run it. Each check takes an *endpoint factory* (a callable returning a fresh,
unserved endpoint), serves it in a thread on a real Zenoh session (a router opened here on
a free loopback port, a random session name, scouting off) and plays the hub against it:
:class:`FakeHub`. A check returns nothing when the endpoint conforms and raises
:class:`AssertionError` naming what it did not do.

Use it from pytest::

    from hub import conformance

    @pytest.mark.parametrize("check", conformance.CHECKS, ids=lambda c: c.__name__)
    def test_my_endpoint_keeps_the_contract(check):
        check(lambda: MyEndpoint(...))

or all at once, ``conformance.run_all(factory)`` (a list of failures, empty if none).

What is checked (docs/contract.md): the description is valid for the role; a run is
accepted, another refused while busy, the same run id re-accepted; every reply carries the
run and the input's window (spikes: ``t0_s``/``t1_s`` exact; sensors: ``t_s <= t1_s``);
stale, future, foreign (no tag, a bad tag, another run, no run) and over-limit inputs are
dropped, counted in the described counters by kind and never stepped on; the input
timeout calls ``make_safe``; a body told something over its limits is made safe;
``RunEnd`` ends the run; the hub vanishing ends it; ``close()`` is called at shutdown.
"""

from __future__ import annotations

import queue
import secrets
import threading
import time
from collections.abc import Callable

from hub import wire
from hub.bus import free_tcp_port, open_session
from hub.config import BusSection
from hub.endpoint import Endpoint
from hub.protocol import (
    OUTPUT_TYPE,
    Description,
    Message,
    MotorCommand,
    RunEnd,
    RunHold,
    RunReply,
    RunStart,
    SensorReading,
    SpikeBatch,
    StepWindow,
    Stimulation,
    merge_parts,
)

Factory = Callable[[], Endpoint]

PERIOD_MS = 10.0
#: a second run's period: an endpoint must take the period the hub announces, not its own
OTHER_PERIOD_MS = 5.0
N_STEPS = 20
INPUT_TIMEOUT_S = 0.3  # the suite shortens the endpoint's input timeout to this
REPLY_TIMEOUT_S = 10.0  # a step of a slow model on a busy machine still answers within this
# Coming up includes a simulator's warm-up, which compiles its kernels when numba's cache
# is cold (a fresh clone): tens of seconds on a busy two-core machine.
START_TIMEOUT_S = 90.0
WINDOW_TOLERANCE_S = 1e-9


def new_run_id() -> str:
    """A fresh run id (32 lowercase hex characters)."""
    return secrets.token_hex(16)


class Instrumented:
    """Counts the hooks an endpoint is given: ``make_safe``, ``start_run``, ``end_run``,
    ``close`` (wrapping the instance's methods, so the endpoint's own still run)."""

    HOOKS = ("make_safe", "start_run", "end_run", "close")

    def __init__(self, endpoint: Endpoint):
        self.calls = dict.fromkeys(self.HOOKS, 0)
        for name in self.HOOKS:
            original = getattr(endpoint, name)

            def counted(*args, _name=name, _original=original):
                self.calls[_name] += 1
                return _original(*args)

            setattr(endpoint, name, counted)


class FakeHub:
    """One endpoint served in a thread, and a hub-side Zenoh session talking to it.

    Parameters
    ----------
    endpoint : Endpoint
        Fresh and not yet served; its ``input_timeout_s`` is set to ``input_timeout_s``.
    """

    def __init__(self, endpoint: Endpoint, *, input_timeout_s: float = INPUT_TIMEOUT_S):
        port = free_tcp_port()
        self.bus = BusSection(
            session=f"conf-{secrets.token_hex(4)}", listen=(f"tcp/127.0.0.1:{port}",)
        )
        self.keys = self.bus.keys
        self.endpoint = endpoint
        self.role, self.id = endpoint.role, endpoint.id
        endpoint.input_timeout_s = input_timeout_s
        self.hooks = Instrumented(endpoint)
        self.session = open_session(self.bus, listener=True)
        self.hub_token = self.session.liveliness().declare_token(self.keys.hub_alive)
        self.outputs: queue.SimpleQueue = queue.SimpleQueue()
        self.alive = threading.Event()
        self._declared = [
            self.session.declare_subscriber(
                self.keys.output(self.role, self.id),
                lambda s: self.outputs.put((s.payload.to_bytes(), s.attachment)),
            ),
            self.session.liveliness().declare_subscriber(
                self.keys.alive(self.role, self.id), lambda s: self.alive.set(), history=True
            ),
        ]
        self.publisher = self.session.declare_publisher(self.keys.input(self.role, self.id))
        self.inbox = wire.Inbox()
        self.run: RunStart | None = None
        self.error: BaseException | None = None
        self.status: int | None = None
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()
        if not self.alive.wait(START_TIMEOUT_S):
            self.close(wait_s=START_TIMEOUT_S)  # it may still be warming up
            raise AssertionError(f"{type(endpoint).__name__} did not come up on the bus")
        self.description = self.describe()
        # the mode runs are announced in: a real device takes realtime runs only
        self.mode = "realtime" if self.description.realtime_only else "lockstep"

    def _serve(self):
        try:
            self.status = self.endpoint.serve(self.bus, install_signals=False)
        except BaseException as exc:
            self.error = exc

    # ------------------------------------------------------------ queries

    def describe(self) -> Description:
        """Query the endpoint's description now (it must answer exactly once)."""
        replies = wire.get(
            self.session, self.keys.describe(self.role, self.id), timeout_s=REPLY_TIMEOUT_S
        )
        assert len(replies) == 1, f"describe gave {len(replies)} replies, not 1"
        return Description.decode(replies[0])

    def counters(self) -> dict:
        """The counters of a fresh description (``{}`` when it has none)."""
        return self.describe().counters or {}

    def dropped(self) -> dict:
        """The inputs the endpoint has dropped so far, counted by kind."""
        return dict(self.counters().get("dropped", {}))

    def _run_query(self, message: Message) -> RunReply:
        replies = wire.get(
            self.session,
            self.keys.run(self.role, self.id),
            message.encode(),
            timeout_s=REPLY_TIMEOUT_S,
        )
        assert len(replies) == 1, f"run gave {len(replies)} replies, not 1"
        return RunReply.decode(replies[0])

    def start(self, run: str | None = None, **fields) -> RunReply:
        """Announce a run (a fresh id and key unless given); keep it as ``self.run`` if taken."""
        start = RunStart(
            run=run or new_run_id(),
            period_ms=fields.pop("period_ms", PERIOD_MS),
            n_steps=fields.pop("n_steps", N_STEPS),
            mode=fields.pop("mode", self.mode),
            start_unix_s=time.time(),
            deadline_ms=fields.pop("deadline_ms", PERIOD_MS),
            key=fields.pop("key", wire.new_key()),
            **fields,
        )
        reply = self._run_query(start)
        if reply.ok and (self.run is None or self.run.run != start.run):
            self.run = start
            self.inbox.key = start.key
        return reply

    def hold(self, hold: bool, run: str | None = None) -> RunReply:
        """Pause (``hold=True``) or resume a run with ``RunHold``; the endpoint's reply.

        Parameters
        ----------
        hold : bool
            True pauses, False resumes.
        run : str, optional
            The run's id; the current run's when not given.
        """
        return self._run_query(RunHold(run=run or self.run.run, hold=hold))

    def end(self, outcome: str = "completed") -> RunReply:
        """End the current run with ``RunEnd`` of ``outcome``; the endpoint's reply."""
        reply = self._run_query(RunEnd(run=self.run.run, outcome=outcome))
        return reply

    # ------------------------------------------------------------ the loop

    def window(
        self, step: int, run: str | None = None, period_ms: float | None = None
    ) -> StepWindow:
        """Step ``step``'s window in the current run (or ``run``), at the run's period
        (or ``period_ms``: a window that is not the run's).

        Parameters
        ----------
        step : int
            The step.
        run : str, optional
            Another run's id.
        period_ms : float, optional
            Another period.
        """
        period_ms = self.run.period_ms if period_ms is None else period_ms
        return StepWindow.of(run or self.run.run, step, period_ms / 1e3)

    def valid_input(
        self,
        step: int,
        *,
        run: str | None = None,
        pulse: bool = False,
        period_ms: float | None = None,
    ) -> Message:
        """An input of ``step`` within the endpoint's limits, in the run's window of that
        step: a body's wheels both at 0.01 m/s (or its limit), a culture's stimulation.

        Parameters
        ----------
        step : int
            The step.
        run : str, optional
            Another run's id for the window.
        pulse : bool
            A culture's input holds one pulse (on its first channel) instead of none.
        period_ms : float, optional
            Another period for the window (an input the endpoint should drop).
        """
        w = self.window(step, run, period_ms)
        d = self.description
        if self.role == "body":
            speed = min(0.01, d.max_wheel_mps)
            return MotorCommand(**w.stamp, left_mps=speed, right_mps=speed)
        if not pulse:
            return Stimulation(**w.stamp)
        return Stimulation(
            **w.stamp,
            channel=[int(d.channel[0])],
            amplitude_ua=[min(10.0, d.max_amplitude_ua or 10.0)],
            width_ms=[min(0.2, d.max_width_ms or 0.2)],
            onset_ms=[0.0],
        )

    def over_limit_input(self, step: int) -> Message | None:
        """An input of ``step`` over a described limit; None if the endpoint describes none."""
        w = self.window(step)
        d = self.description
        if self.role == "body":
            top = d.max_wheel_mps
            return MotorCommand(**w.stamp, left_mps=top * 1.5 + 0.1, right_mps=0.0)
        if d.max_amplitude_ua is None:
            return None
        return Stimulation(
            **w.stamp,
            channel=[int(d.channel[0])],
            amplitude_ua=[d.max_amplitude_ua * 1.5 + 1.0],
            width_ms=[min(0.2, d.max_width_ms or 0.2)],
            onset_ms=[0.0],
        )

    def send(self, message: Message | bytes, *, key: bytes | None | str = "run") -> None:
        """Put an input on the endpoint's input key.

        Parameters
        ----------
        message : Message or bytes
            The input, or a payload as it is to go on the bus.
        key : bytes, None or "run"
            ``"run"`` seals it with the current run's key; bytes with that key; None puts
            it unsealed (no attachment at all).
        """
        payload = message if isinstance(message, bytes) else message.encode()
        if key is None:
            self.publisher.put(payload)
            return
        wire.Outbox(self.publisher, self.run.key if key == "run" else key).put(payload)

    def reply(self, timeout_s: float = REPLY_TIMEOUT_S) -> Message:
        """The next output, authenticated with the run's key and decoded; a culture's
        parts streamed before it (contract v4) merged into it, as the hub does, each
        checked to be of the same step and window."""
        deadline = time.monotonic() + timeout_s
        parts: list[SpikeBatch] = []
        while True:
            left = deadline - time.monotonic()
            try:
                payload, attachment = self.outputs.get(timeout=max(left, 0.0))
            except queue.Empty:
                raise AssertionError(f"no output within {timeout_s} s") from None
            whole = self.inbox.feed(payload, attachment)  # WireError: not sealed by the key
            if whole is None:
                continue
            output = OUTPUT_TYPE[self.role].decode(whole)
            if getattr(output, "partial", None):
                parts.append(output)
                continue
            for part in parts:
                check_reply(part, output.window)
            return merge_parts(parts, output) if parts else output

    def step(self, step: int, **kw) -> Message:
        """Send a valid input of ``step`` and return its checked reply."""
        self.send(self.valid_input(step, **kw))
        out = self.reply()
        check_reply(out, self.window(step))
        return out

    def vanish(self) -> None:
        """The hub's liveliness token goes away (as when the hub dies)."""
        self.hub_token.undeclare()

    def close(self, wait_s: float = REPLY_TIMEOUT_S) -> None:
        """Stop the endpoint (it must return from serve within ``wait_s``) and close the
        hub's session."""
        self.endpoint.request_stop()
        self.thread.join(wait_s)
        self.session.close()
        assert not self.thread.is_alive(), "serve() did not return after request_stop()"


def check_reply(output: Message, window: StepWindow) -> None:
    """Assert that ``output`` answers an input of ``window``: same run and step, and the
    input's window (spikes: ``t0_s``/``t1_s`` within :data:`WINDOW_TOLERANCE_S`; sensors:
    read by ``t1_s``).

    Parameters
    ----------
    output : Message
        The endpoint's reply.
    window : StepWindow
        The input's window.

    Raises
    ------
    AssertionError
        Naming what does not match.
    """
    assert output.run == window.run, f"reply of run {output.run!r}, not {window.run!r}"
    assert output.step == window.step, f"reply of step {output.step}, not {window.step}"
    if isinstance(output, SpikeBatch):
        assert abs(output.t0_s - window.t0_s) <= WINDOW_TOLERANCE_S, "spikes' t0_s"
        assert abs(output.t1_s - window.t1_s) <= WINDOW_TOLERANCE_S, "spikes' t1_s"
    elif isinstance(output, SensorReading):
        assert output.t_s <= window.t1_s + WINDOW_TOLERANCE_S, "sensors read after t1_s"


class served:
    """``with served(factory) as hub:`` a :class:`FakeHub` closed afterwards."""

    def __init__(self, factory: Factory):
        self.factory = factory

    def __enter__(self) -> FakeHub:
        self.hub = FakeHub(self.factory())
        return self.hub

    def __exit__(self, *exc):
        if self.hub.thread.is_alive():
            self.hub.close()
        else:
            self.hub.session.close()
        if exc[0] is None and self.hub.error is not None:
            raise AssertionError(f"serve() failed: {self.hub.error!r}") from self.hub.error


# ---------------------------------------------------------------- the checks


def check_describe(factory: Factory) -> None:
    """``describe`` answers one valid description of the endpoint's role, with counters."""
    with served(factory) as hub:
        d = hub.description
        assert d.role == hub.role and d.id == hub.id, (d.role, d.id)
        assert d.kind, "a description names its kind"
        assert isinstance(d.counters, dict) and "dropped" in d.counters
        if hub.role == "body":
            assert d.max_wheel_mps is not None and d.max_wheel_mps > 0
        for name in ("max_amplitude_ua", "max_width_ms", "max_pulse_hz"):
            value = getattr(d, name)
            assert value is None or value >= 0, f"{name} {value}"


def check_run_lifecycle(factory: Factory) -> None:
    """A run accepted; another refused while busy (naming the busy run); the same id
    re-accepted; RunEnd ends it; then a new run is accepted and starts at step 0."""
    with served(factory) as hub:
        first = hub.start()
        assert first.ok, f"RunStart refused: {first.reason}"
        run = hub.run.run
        other = hub.start()
        assert not other.ok and run in other.reason, f"a second run: {other}"
        again = hub.start(run=run, key=hub.run.key)
        assert again.ok, f"the same run id refused: {again.reason}"
        hub.step(0)
        hub.step(1)
        assert hub.end().ok
        assert hub.hooks.calls["end_run"] >= 1, "RunEnd did not call end_run()"
        assert hub.counters().get("run", "") == "", "still in a run after RunEnd"
        hub.run = None
        assert hub.start().ok, "a new run refused after RunEnd"
        hub.step(0)  # the new run starts at step 0 again


def check_replies_carry_run_and_window(factory: Factory) -> None:
    """Every step's reply carries the run and its input's window, in a run of every step
    up to ``n_steps`` (the last one being the hub's final stop); and in a second run at
    another period, the windows of that period (the hub's, announced with the run)."""
    with served(factory) as hub:
        assert hub.start(n_steps=5).ok
        for k in range(6):
            hub.step(k, **({"pulse": True} if hub.role == "culture" and k == 2 else {}))
        assert hub.counters()["steps"] == 6
        assert hub.end().ok
        hub.run = None
        assert hub.start(n_steps=3, period_ms=OTHER_PERIOD_MS, deadline_ms=OTHER_PERIOD_MS).ok
        for k in range(4):
            hub.step(k)  # checked against the windows of OTHER_PERIOD_MS


def check_bad_inputs_are_dropped_and_counted(factory: Factory) -> None:
    """Inputs with no run, stale, future, foreign (unsealed, a bad tag, another run), in a
    window that is not the run's, and over-limit ones are dropped, counted by kind, and
    never stepped on."""
    with served(factory) as hub:
        hub.run = RunStart(
            run=new_run_id(),
            period_ms=PERIOD_MS,
            n_steps=N_STEPS,
            mode="lockstep",
            start_unix_s=0.0,
            deadline_ms=PERIOD_MS,
            key=wire.new_key(),
        )
        hub.send(hub.valid_input(0))  # before any run: foreign
        hub.run = None
        assert hub.start(n_steps=N_STEPS).ok
        hub.step(0)
        hub.step(1)
        expected = {"foreign": 1}
        hub.send(hub.valid_input(1))  # stale
        hub.send(hub.valid_input(N_STEPS + 1))  # future: beyond the final stop
        hub.send(hub.valid_input(2), key=None)  # unsealed
        hub.send(hub.valid_input(2), key=wire.new_key())  # sealed with another key
        hub.send(hub.valid_input(2, run=new_run_id()))  # another run, sealed with this key
        hub.send(hub.valid_input(2, period_ms=2 * PERIOD_MS))  # another period's window
        expected |= {"stale": 1, "future": 1, "foreign": 4, "window": 1}
        over = hub.over_limit_input(2)
        safe_before = hub.hooks.calls["make_safe"]
        if over is not None:
            hub.send(over)
            expected["limit"] = 1
        hub.step(3)  # the next reply is step 3's: nothing in between was stepped on
        dropped = hub.dropped()
        for kind, n in expected.items():
            assert dropped.get(kind, 0) == n, f"dropped {dropped}, expected {expected}"
        assert hub.counters()["steps"] == 3
        if over is not None and hub.role == "body":
            assert hub.hooks.calls["make_safe"] > safe_before, "over its limits: not stopped"


def check_input_timeout_makes_safe(factory: Factory) -> None:
    """Silence during a run longer than the input timeout calls ``make_safe``."""
    with served(factory) as hub:
        assert hub.start().ok
        hub.step(0)
        before = hub.hooks.calls["make_safe"]
        _wait_for(lambda: hub.hooks.calls["make_safe"] > before, INPUT_TIMEOUT_S * 20)


def check_pause_makes_safe(factory: Factory) -> None:
    """A paused run (``RunHold``) makes the endpoint safe at once; another run's hold is
    refused; after the resume the run goes on."""
    with served(factory) as hub:
        assert hub.start().ok
        hub.step(0)
        before = hub.hooks.calls["make_safe"]
        assert hub.hold(True).ok
        assert hub.hooks.calls["make_safe"] > before, "paused: not made safe"
        assert not hub.hold(True, run=new_run_id()).ok, "another run's pause taken"
        assert hub.hold(False).ok
        hub.step(1)


def check_hub_vanishing_ends_the_run(factory: Factory) -> None:
    """When the hub's liveliness token goes, the endpoint makes itself safe and is idle."""
    with served(factory) as hub:
        assert hub.start().ok
        hub.step(0)
        hub.vanish()
        _wait_for(lambda: hub.hooks.calls["end_run"] >= 1, REPLY_TIMEOUT_S)
        assert hub.counters().get("run", "") == "", "still in a run after the hub vanished"


def check_lockstep_only_for_simulators(factory: Factory) -> None:
    """A real device (``realtime_only``) refuses a lockstep run, saying why; any other
    endpoint takes one."""
    with served(factory) as hub:
        reply = hub.start(mode="lockstep")
        if hub.description.realtime_only:
            assert not reply.ok and "real time" in reply.reason, f"lockstep: {reply}"
            assert hub.start(mode="realtime").ok, "a realtime run refused"
        else:
            assert reply.ok, f"a lockstep run refused: {reply.reason}"


def check_close_at_shutdown(factory: Factory) -> None:
    """A stop request ends ``serve`` with status 0 and calls ``close()`` once."""
    with served(factory) as hub:
        assert hub.start().ok
        hub.step(0)
        hub.close()
        assert hub.status == 0 and hub.error is None, (hub.status, hub.error)
        assert hub.hooks.calls["close"] == 1


CHECKS = (
    check_describe,
    check_run_lifecycle,
    check_replies_carry_run_and_window,
    check_bad_inputs_are_dropped_and_counted,
    check_input_timeout_makes_safe,
    check_pause_makes_safe,
    check_hub_vanishing_ends_the_run,
    check_lockstep_only_for_simulators,
    check_close_at_shutdown,
)


def run_all(factory: Factory) -> list[str]:
    """Run every check on endpoints from ``factory``; the failures, as lines (none: [])."""
    failures = []
    for check in CHECKS:
        try:
            check(factory)
        except AssertionError as exc:
            failures.append(f"{check.__name__}: {exc}")
    return failures


def _wait_for(condition: Callable[[], bool], timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("condition not reached in time")
        time.sleep(0.01)


__all__ = ["CHECKS", "FakeHub", "check_reply", "run_all", "served"]
