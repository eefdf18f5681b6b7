"""``neuvision dashboard``: a source (live or replay), the state, the server, put together."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from hub.config import ExperimentConfig

from .state import FrameState


def run_dashboard(
    cfg: ExperimentConfig,
    *,
    replay: str | Path | None = None,
    speed: float = 1.0,
    host: str | None = None,
    port: int | None = None,
    announce: Callable[[str], None] = print,
    follow_local: bool = False,
) -> None:
    """Serve the dashboard until SIGINT/SIGTERM.

    Parameters
    ----------
    cfg : ExperimentConfig
        The bus to observe (``[bus]``: session, where the hub listens or ``bus.connect``)
        and where to serve (``[dashboard]``).
    replay : path, optional
        A run folder to replay instead of watching the bus.
    speed : float
        The replay's speed (× real time).
    host, port : optional
        Override ``dashboard.host`` and ``dashboard.port`` (0: a free port).
    announce : callable
        Called with the line that says where the page is.
    follow_local : bool
        No address was given: follow the session's hub on this machine from run to run
        (:mod:`hub.local_hubs`; each ``neuvision run`` listens on a port of its own).

    Raises
    ------
    dashboard.server.ServeError
        The address cannot be served on.
    dashboard.replay.ReplayError
        The run folder cannot be replayed.
    """
    from .server import serve  # the web stack only when serving

    state = FrameState()
    if replay is not None:
        from .replay import ReplaySource

        source = ReplaySource(replay, state, speed=speed)
        what = f"replay of {replay} at {speed:g}x"
    else:
        from hub.scheduling import yield_cpu

        from .observer import BusObserver

        # before the bus's and the server's threads start: they inherit it
        scheduling = yield_cpu() if cfg.dashboard.yield_cpu else "normal: dashboard.yield_cpu"
        # the dashboard's own experiment file, if it was given one, stands in for the hub's
        source = BusObserver(
            cfg.bus,
            state,
            cfg.to_dict() if cfg.source else None,
            find_hub=_local_hub_finder(cfg.bus.session) if follow_local else None,
        )
        what = f"live: session {cfg.bus.session!r}, hub at {source.where}; scheduling {scheduling}"
    serve(
        source,
        state,
        host=host or cfg.dashboard.host,
        port=cfg.dashboard.port if port is None else port,
        fps=cfg.dashboard.fps,
        on_ready=lambda url: announce(f"dashboard at {url} ({what}); Ctrl-C ends it"),
    )


def _local_hub_finder(session: str) -> Callable[[], tuple[str, ...] | None]:
    """Where the one hub of ``session`` on this machine listens, asked anew each time
    (None: none, or several)."""
    from hub import local_hubs

    def find() -> tuple[str, ...] | None:
        try:
            found = local_hubs.find(session)
        except (local_hubs.AmbiguousSession, OSError):
            return None
        return tuple(found.locators) if found is not None else None

    return find
