"""The hub's side of the bus: what it declares, sends and queries, and what it hears.

A thin layer over one Zenoh session: the input publishers (each through a sealing
:class:`~hub.wire.Outbox`), one subscription for every endpoint's output (unsealed and
reassembled by a :class:`~hub.wire.Inbox` per endpoint), the liveliness of every
participant, the control queryable, the status publisher and the hub's own liveliness
token. What it hears becomes plain event tuples handed to ``deliver``::

    ("rx", role, payload, t_wall_ns, t_monotonic)       # a reply, unsealed and whole
    ("refused", role, payload, kind, detail, t_wall_ns)  # not its endpoint's, or broken
    ("alive", key, present)                               # a liveliness token came or went
    ("control", query)                                    # a query on hub/control
    ("status", query)                                     # a query on hub/status

The loop decides what the events mean; nothing here keeps loop state.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import zenoh

from hub import wire
from hub.bus import LOOP_PUBLISH, TELEMETRY_PUBLISH, payload_bytes
from hub.protocol import ROLES, Keys
from hub.shelf import Shelf


class HubLink:
    """The hub's declarations on ``session`` for one run.

    Parameters
    ----------
    session : zenoh.Session
        The hub's session (it is the router).
    keys : Keys
        The session's key expressions.
    ids : dict
        Role → id of the body and culture of the run.
    run_keys : dict
        Role → that endpoint's run key (sealing both ways).
    deliver : callable
        Called with each event tuple, on Zenoh's threads (replies of one subscription come
        on one thread, in order).
    """

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        ids: dict[str, str],
        run_keys: dict[str, bytes],
        deliver: Callable[[tuple], None],
    ):
        self.session = session
        self._deliver = deliver
        self.keys = keys
        self._observer: Shelf | None = None  # the burst observer's spikes (watch_observer)
        # One subscription for both replies: Zenoh gives each subscription its own Python
        # thread, and two would hand the interpreter and the loop's lock back and forth
        # every step. That thread is kept (Zenoh's default, indirect): the callback run in
        # Zenoh's own thread waits there for the interpreter, holding the link up (a
        # lockstep closed loop 18 % slower). Keys are told apart here; the hub's own
        # publications are not delivered to it (remote origin only).
        role_of = {keys.output(role, i): role for role, i in ids.items()}
        inboxes = {role: wire.Inbox(run_keys[role]) for role in ROLES}
        abandoned = dict.fromkeys(ROLES, 0)

        def on_output(sample):
            role = role_of.get(str(sample.key_expr))
            if role is None:  # another endpoint's output
                return
            inbox = inboxes[role]
            try:
                raw = inbox.feed(sample.payload)  # sealed: the seal ends the payload
            except wire.WireError as exc:
                deliver(
                    ("refused", role, payload_bytes(sample), exc.kind, str(exc), time.time_ns())
                )
                return
            if inbox.abandoned != abandoned[role]:
                abandoned[role] = inbox.abandoned
                deliver(("refused", role, b"", "frame", "an incomplete message", time.time_ns()))
            if raw is not None:  # else: more frames to come
                deliver(("rx", role, raw, time.time_ns(), time.monotonic()))

        self.outboxes = {
            role: wire.Outbox(
                session.declare_publisher(keys.input(role, i), **LOOP_PUBLISH), run_keys[role]
            )
            for role, i in ids.items()
        }
        self._status = session.declare_publisher(keys.hub_status, **TELEMETRY_PUBLISH)
        # the views for live displays, handed to those that ask (hub/view.py): answered in
        # Zenoh's thread from what the loop's thread left on the shelf
        self.views = Shelf()
        # Zenoh undeclares what is garbage-collected: keep every declaration.
        self._declared = [
            session.declare_subscriber(
                keys.outputs_all, on_output, allowed_origin=zenoh.Locality.REMOTE
            ),
            session.liveliness().declare_subscriber(
                keys.alive_all,
                lambda s: deliver(("alive", str(s.key_expr), s.kind == zenoh.SampleKind.PUT)),
                history=True,
            ),
            session.declare_queryable(keys.hub_control, lambda q: deliver(("control", q))),
            # the status on request, for observers that may not send control commands
            session.declare_queryable(keys.hub_status, lambda q: deliver(("status", q))),
            self.views.declare(session, keys.hub_view),
            session.liveliness().declare_token(keys.hub_alive),
        ]

    def watch_observer(self, name: str, key: bytes, keep: int) -> None:
        """Declare the run's exchange with a burst observer: the spikes left for it to ask
        for (:meth:`forward_spikes`) and its reports, each one whole delivered as
        ``("report", raw)``, one that does not unseal as ``("report_refused", kind,
        detail)``.

        Parameters
        ----------
        name : str
            The observer's name (in its keys).
        key : bytes
            The run key that seals the exchange both ways.
        keep : int
            How many of the latest spike messages are kept for it to ask for.
        """
        inbox = wire.Inbox(key)

        def on_report(sample):
            try:
                raw = inbox.feed(sample.payload)
            except wire.WireError as exc:
                self._deliver(("report_refused", exc.kind, str(exc)))
                return
            if raw is not None:
                self._deliver(("report", raw))

        # kept for the observer to ask for, not published (hub/shelf.py): an observer that
        # stopped reading held the loop up
        self._observer = Shelf(keep, key=key)
        self._declared += [
            self._observer.declare(self.session, self.keys.observer_spikes(name)),
            self.session.declare_subscriber(self.keys.observer_reports(name), on_report),
        ]

    def forward_spikes(self, raw: bytes) -> None:
        """Leave an ``ObservedSpikes`` for the burst observer to ask for (answered sealed;
        framed if large)."""
        self._observer.put(raw)

    def send(self, role: str, raw: bytes) -> None:
        """Put an input to an endpoint, sealed with its run key (framed if large).

        Parameters
        ----------
        role : str
            ``"body"`` or ``"culture"``.
        raw : bytes
            The encoded input.
        """
        self.outboxes[role].put(raw)

    def publish_status(self, raw: bytes) -> None:
        """Put a ``HubStatus`` for observers (newest wins; never blocks)."""
        self._status.put(raw)

    def view_observed(self) -> bool:
        """Whether anyone asked for views lately (a live display)."""
        return self.views.watched()

    def publish_view(self, raw: bytes) -> None:
        """Leave a ``HubView`` for the observers that ask."""
        self.views.put(raw)

    def query(self, key: str, payload: bytes | None = None, *, timeout_s: float) -> list[bytes]:
        """The whole payloads of every reply to a query (``describe``, ``run``).

        Parameters
        ----------
        key : str
            The key expression queried.
        payload : bytes, optional
            The query's payload.
        timeout_s : float
            How long to wait for replies.
        """
        return wire.get(self.session, key, payload, timeout_s=timeout_s)
