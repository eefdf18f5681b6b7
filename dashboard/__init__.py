"""The live dashboard and replay: a run in a browser (docs/dashboard.md).

``neuvision dashboard`` (and ``neuvision run --dashboard``) serves a page that shows a run as it
goes, with pause, resume and stop; ``--replay RUN_DIR`` plays a recorded run through the same
page. The data flow, one module each:

- :mod:`dashboard.observer` — the live source: an observer on the bus (the hub's ``hub/view``
  and ``hub/status``, the endpoints' descriptions), controls to ``hub/control``;
- :mod:`dashboard.replay` — the replay source: a run folder, its own clock;
- :mod:`dashboard.scene` — what does not change in a run (arena, body, channel layout);
- :mod:`dashboard.state` — the newest values and short histories, as frames for each page;
- :mod:`dashboard.server` — the web server (Starlette, uvicorn): the page, frames on a websocket;
- :mod:`dashboard.app` — the command put together;
- ``dashboard/static/`` — the page (HTML, one script drawing on canvases, CSS).

The web stack is an optional extra (``pip install 'neuvision[dashboard]'``); nothing else in
the project imports this package but ``hub/cli.py``.
"""
