"""A bare watcher of the hub's views, for benchmarks: it asks a session's hub on this
machine for its views (``hub/view/*``), as the dashboard does, 30 times a second, and
takes them without decoding them (``bench/dashboard_within.py --watcher bare``): what the
views cost the loop with no dashboard's work on them.

    python bench/view_watcher.py SESSION
    python bench/view_watcher.py SESSION --toggled   # asking only between SIGUSR1 and
                                                     # SIGUSR2 (bench/dashboard_toggle.py)
    python bench/view_watcher.py SESSION --idle      # under SCHED_IDLE, as the dashboard
"""

from __future__ import annotations

import json
import signal
import sys
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hub import local_hubs  # noqa: E402
from hub.bus import open_session  # noqa: E402
from hub.config import load_config  # noqa: E402
from hub.shelf import Asker  # noqa: E402


def main() -> None:
    session_name = sys.argv[1]
    if "--idle" in sys.argv[2:]:  # before Zenoh starts its threads: they inherit it
        from hub.scheduling import yield_cpu

        yield_cpu()
    found = local_hubs.find(session_name)
    if found is None:
        raise SystemExit(f"no hub of session {session_name!r} on this machine")
    connect = f"bus.connect={json.dumps(list(found.locators))}"
    # as the dashboard's observer: Zenoh's queued transport (dashboard/observer.py)
    cfg = load_config(
        None, [f"bus.session={json.dumps(session_name)}", connect, "bus.low_latency=false"]
    )
    session = open_session(cfg.bus, listener=False, role="observer")
    subscribed = threading.Event()
    if "--toggled" in sys.argv[2:]:
        signal.signal(signal.SIGUSR1, lambda *_: subscribed.set())
        signal.signal(signal.SIGUSR2, lambda *_: subscribed.clear())
    else:
        subscribed.set()
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    asker, taken = Asker(session, cfg.bus.keys.hub_view), 0
    while not done.wait(1 / 30):
        if subscribed.is_set():  # asks again once answered; unasked, the hub stops sending
            taken += len(asker.take())
    print(f"views taken: {taken}", flush=True)
    session.close()


if __name__ == "__main__":
    main()
