"""The dashboard in a browser: Playwright drives a headless Chromium through a closed-loop run
with `neuvision run --dashboard`, then through the replay of the run's folder.

Checked: the robot moves across frames, the raster fills, Pause stops the step counter and
Resume restarts it, Stop ends the run with outcome `stopped`, and the replay shows the same
trajectory as the record and as the live page; the raster, drawn frame by frame, shows
every spike the page keeps and no stale one. Measured and printed: the page's frame rate
(frames received and drawn) and its lag behind the hub (from the hub's receipt of a step's
reading, as the record stamps it, to the page drawing that step). Screenshots stay in the
test's folder; NEUVISION_SCREENSHOTS=DIR also copies the live one there as dashboard.png
(the picture of docs/dashboard.md and the README: NEUVISION_SCREENSHOTS=docs/img).

Chromium: Debian's `chromium` package (what .ci/run installs), or Playwright's own if
`python -m playwright install chromium` was run; the test is skipped without either.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from hub.bus import free_tcp_port
from hub.protocol import SensorReading
from hub.record import read_run
from tests.dashboard.synthetic import write_run

pytestmark = [pytest.mark.bus, pytest.mark.browser]

ROOT = Path(__file__).resolve().parents[2]
TIMEOUT_MS = 60_000

# Frames received and drawn, the page's clock, and its time taking and drawing frames.
PAGE_COUNTS = (
    "[nv.stats.received, nv.stats.drawn, performance.now(), nv.stats.takeMs, nv.stats.drawMs]"
)
# Coloured pixels of the raster's canvas (spikes are red or blue dots on white).
RASTER_PIXELS = """() => {
  const c = document.getElementById("raster");
  const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
  let n = 0;
  for (let k = 0; k < d.length; k += 4) if (d[k + 3] > 0 && Math.abs(d[k] - d[k + 2]) > 60) n++;
  return n;
}"""

# The raster's spikes against the page's own list of them (nv.spikes): each spike kept that
# falls in the window shown is painted its type's colour at its column and row, and no
# spike-coloured pixel stands where no kept spike is (a column not cleared when time came
# round to it again). The geometry is the page's: a column per device pixel of the raster,
# RASTER_S seconds across, rows from 12 px below the top to 16 px above the bottom.
RASTER_AGAINST_SPIKES = """() => {
  const c = document.getElementById("raster"), w = c.width, h = c.height;
  const d = c.getContext("2d").getImageData(0, 0, w, h).data;
  const ratio = window.devicePixelRatio || 1, top = 12 * ratio, bottom = h - 16 * ratio;
  const cul = nv.scene.culture, n = cul.channel.length, rowH = (bottom - top) / n;
  const colMs = RASTER_S * 1000 / w, now = Math.floor(nv.t_s * 1000 / colMs);
  const oldest = now - w + 1, dotW = Math.max(1, Math.round(1.2 * ratio));
  const colours = [[192, 57, 43], [46, 111, 216]];  // excitatory, inhibitory
  const rowY = (i) => Math.floor(top + (i + 0.5) * rowH);
  const colourAt = (x, y) => {
    const k = 4 * (y * w + x);
    return colours.findIndex((col) => col.every((v, j) => Math.abs(d[k + j] - v) <= 3));
  };
  const expected = new Set(), wrong = [];
  let shown = 0;
  for (const chunk of nv.spikes) {
    for (let k = 0; k < chunk.t.length; k++) {
      const col = Math.floor((chunk.t0 + chunk.t[k]) / colMs), i = chunk.i[k];
      if (col < oldest || col > now) continue;
      const type = cul.cell_type && cul.cell_type[i] === 1 ? 1 : 0;
      const x0 = col - oldest;
      for (let x = x0; x < Math.min(x0 + dotW, w); x++) expected.add(`${x},${i}`);
      shown += 1;
      if (colourAt(col - oldest, rowY(i)) !== type) wrong.push([col - oldest, i]);
    }
  }
  const stray = [];
  for (let i = 0; i < n; i++) {
    for (let x = 0; x < w; x++) {
      if (colourAt(x, rowY(i)) >= 0 && !expected.has(`${x},${i}`)) stray.push([x, i]);
    }
  }
  return { shown, nWrong: wrong.length, nStray: stray.length,
           wrong: wrong.slice(0, 10), stray: stray.slice(0, 10) };
}"""


@pytest.fixture(scope="module")
def chromium() -> str:
    """A Chromium to drive: the system's, else Playwright's own; skip without one."""
    pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        path = pw.chromium.executable_path
    if path and os.path.exists(path):
        return path
    pytest.skip(
        "no Chromium: install Debian's (apt-get install chromium) or Playwright's own "
        "(python -m playwright install chromium)"
    )


def _serving(url: str, proc: subprocess.Popen, timeout_s: float = 90.0) -> None:
    """Wait until ``url`` answers (the process must not end meanwhile)."""
    deadline = time.monotonic() + timeout_s
    while True:
        assert proc.poll() is None, f"the process ended with status {proc.returncode}"
        try:
            urllib.request.urlopen(url, timeout=2).read()
            return
        except OSError:
            assert time.monotonic() < deadline, f"{url} did not answer in {timeout_s} s"
            time.sleep(0.1)


def _open_page(pw, chromium: str, port: int, errors: list[str]):
    """A headless Chromium showing the dashboard served on ``port``; the page's script
    errors go to ``errors``. Returns the browser (to close) and the page."""
    browser = pw.chromium.launch(executable_path=chromium, headless=True)
    page = browser.new_page(viewport={"width": 1400, "height": 1150})
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"http://127.0.0.1:{port}/")
    return browser, page


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _keep(live: Path) -> None:
    """Copy the live screenshot to NEUVISION_SCREENSHOTS, if set (docs/img for the README)."""
    folder = os.environ.get("NEUVISION_SCREENSHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        shutil.copy(live, Path(folder) / "dashboard.png")


def test_a_run_watched_paused_resumed_and_stopped_in_a_browser_then_replayed(
    tmp_path, bus_overrides, chromium, capsys
):
    from playwright.sync_api import sync_playwright

    runs = tmp_path / "runs"
    port = free_tcp_port()
    sets = [a for o in bus_overrides if not o.startswith("bus.listen") for a in ("--set", o)]
    run_log = open(tmp_path / "run.log", "w")
    run = subprocess.Popen(
        [sys.executable, "-m", "hub.cli", "run", "configs/closed_loop.toml", "--quiet"]
        + ["--mode", "realtime", "--duration-s", "300", "--runs-dir", str(runs), "--dashboard"]
        + ["--set", f"dashboard.port={port}", *sets],
        stdout=run_log,
        stderr=subprocess.STDOUT,
        cwd=ROOT,
    )
    shots = {}
    try:
        _serving(f"http://127.0.0.1:{port}/", run)
        with sync_playwright() as pw:
            errors: list[str] = []
            browser, page = _open_page(pw, chromium, port, errors)
            page.wait_for_function(
                "nv.stats.connected && nv.scene && nv.scene.culture && nv.step >= 100",
                timeout=TIMEOUT_MS,
            )
            # the robot moves across frames
            x0, y0 = page.evaluate("nv.pose.slice(0, 2)")
            page.wait_for_function(
                f"Math.hypot(nv.pose[0] - {x0}, nv.pose[1] - {y0}) > 0.003", timeout=TIMEOUT_MS
            )
            # the raster fills
            page.wait_for_function("nv.stats.rasterSpikes > 200", timeout=TIMEOUT_MS)
            painted = page.evaluate(RASTER_PIXELS)
            # the page's frame rate over three seconds of the run
            # (frames received from the dashboard, and drawn: a page busier than the
            # frames' period draws fewer than it receives), and its time taking and drawing
            r0, d0, w0, take0, draw0 = page.evaluate(PAGE_COUNTS)
            page.wait_for_function(f"performance.now() > {w0} + 3000", timeout=TIMEOUT_MS)
            r1, d1, w1, take1, draw1 = page.evaluate(PAGE_COUNTS)
            fps = (r1 - r0) / ((w1 - w0) / 1e3)
            drawn_fps = (d1 - d0) / ((w1 - w0) / 1e3)
            take_ms = (take1 - take0) / max(r1 - r0, 1)
            draw_ms = (draw1 - draw0) / max(d1 - d0, 1)
            shots["dashboard.png"] = tmp_path / "dashboard.png"
            page.screenshot(path=shots["dashboard.png"], full_page=True)
            # pause: the step counter stops while the hub's statuses go on
            page.click("#btn-pause")
            page.wait_for_function("nv.status.state === 'paused'", timeout=TIMEOUT_MS)
            # a view sent before the pause may still arrive after the status saying so:
            # the counter is read once the statuses have gone on for a second, and again
            # a second later
            hub_paused_at, wall = page.evaluate("[nv.status.step, nv.status.wall_s]")
            page.wait_for_function(f"nv.status.wall_s > {wall} + 1.0", timeout=TIMEOUT_MS)
            paused_at, wall = page.evaluate("[nv.step, nv.status.wall_s]")
            page.wait_for_function(f"nv.status.wall_s > {wall} + 1.0", timeout=TIMEOUT_MS)
            still, hub_still = page.evaluate("[nv.step, nv.status.step]")
            shots["dashboard-paused.png"] = tmp_path / "dashboard-paused.png"
            page.screenshot(path=shots["dashboard-paused.png"], full_page=True)
            # resume: it counts again
            page.click("#btn-resume")
            page.wait_for_function(
                f"nv.status.state === 'running' && nv.step > {still + 20}", timeout=TIMEOUT_MS
            )
            # stop (the button asks to be pressed twice)
            page.click("#btn-stop")
            page.click("#btn-stop")
            page.wait_for_function(
                "nv.status.state === 'stopped' || !nv.stats.connected", timeout=TIMEOUT_MS
            )
            # what the header says now: how the run ended, or that the news stopped
            ended_text = page.inner_text("#state")
            live_trace = page.evaluate("nv.trace")
            browser.close()
        code = run.wait(timeout=120)
    finally:
        _stop(run)
        run_log.close()
    log = (tmp_path / "run.log").read_text()
    assert code == 0, log
    assert errors == []
    assert painted > 200
    assert still == paused_at, (paused_at, still)  # the page's counter stands still
    assert hub_still <= hub_paused_at + 1, (hub_paused_at, hub_still)  # the step in flight may end
    assert still <= hub_still, (still, hub_still)  # the page shows no step the hub did not do
    (run_dir,) = runs.iterdir()
    rec = read_run(run_dir)
    assert rec.manifest["outcome"] == "stopped", rec.manifest.get("reason")
    assert rec.manifest["reason"] == "stopped by control"
    assert ended_text in (
        "ended: stopped (stopped by control)",  # the final status came
        "unknown (no news since the dashboard went)",  # the dashboard ended with the run first
    ), ended_text

    # the lag behind the hub: the page's drawing of a step minus the hub's receipt of it
    received_ms = {}
    for f in rec.frames:
        if f.direction == "rx" and f.key.endswith("/sensors"):
            received_ms[SensorReading.decode(f.payload).step] = f.t_wall_ns / 1e6
    first_drawn: dict[int, float] = {}
    for step, drawn_ms, *_ in live_trace:
        first_drawn.setdefault(step, drawn_ms)
    lags = np.array([t - received_ms[s] for s, t in first_drawn.items() if s in received_ms])
    assert lags.size > 50

    # the replay of the run's folder shows the same trajectory
    t_s, poses = rec.trajectory()
    by_step = {int(round(t / 0.01)) - 1: p for t, p in zip(t_s, poses, strict=True)}
    rport = free_tcp_port()
    replay = subprocess.Popen(
        [sys.executable, "-m", "hub.cli", "dashboard", "--replay", str(run_dir)]
        + ["--speed", "4", "--port", str(rport)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        cwd=ROOT,
    )
    try:
        _serving(f"http://127.0.0.1:{rport}/", replay)
        with sync_playwright() as pw:
            browser, page = _open_page(pw, chromium, rport, errors)
            page.wait_for_function("nv.replay && nv.trace.length > 40", timeout=TIMEOUT_MS)
            # a jump with the slider, to the middle of the run
            middle = float(t_s[len(t_s) // 2])
            page.eval_on_selector(
                "#slider",
                "(el, t) => { el.value = t; el.dispatchEvent(new Event('change')); }",
                middle,
            )
            page.wait_for_function(
                f"nv.stats.resets >= 2 && Math.abs(nv.t_s - {middle}) < 1.0", timeout=TIMEOUT_MS
            )
            drawn = page.evaluate("nv.stats.drawn")
            page.wait_for_function(f"nv.stats.drawn > {drawn + 20}", timeout=TIMEOUT_MS)
            shots["dashboard-replay.png"] = tmp_path / "dashboard-replay.png"
            page.screenshot(path=shots["dashboard-replay.png"], full_page=True)
            replay_trace = page.evaluate("nv.trace")
            browser.close()
    finally:
        _stop(replay)
    assert replay.returncode == 0 and errors == []
    replayed = {step: (x, y) for step, _, x, y, _ in replay_trace}
    live = {step: (x, y) for step, _, x, y, _ in live_trace}
    assert len(replayed) > 20 and min(replayed) < middle / 0.01 < max(replayed)
    # the page's poses, live and replayed, are exactly the record's
    assert all(tuple(by_step[s][:2]) == xy for s, xy in replayed.items())
    assert all(tuple(by_step[s][:2]) == xy for s, xy in live.items())
    shared = set(replayed) & set(live)
    _keep(shots["dashboard.png"])
    with capsys.disabled():
        print(
            f"\ndashboard in Chromium: {fps:.1f} frames/s received, {drawn_fps:.1f} drawn "
            f"(the page's time a frame: {take_ms:.2f} ms taking it, {draw_ms:.2f} ms drawing "
            f"it); lag behind the hub (its receipt of a "
            f"step's reading to the page drawing it) median {np.median(lags):.0f} ms, p95 "
            f"{np.percentile(lags, 95):.0f} ms, max {lags.max():.0f} ms over {lags.size} steps; "
            f"replay: {len(replayed)} steps drawn, {len(shared)} also drawn live, all at the "
            f"record's poses; screenshots in {tmp_path}"
        )


@pytest.mark.slow  # a browser through a replay
def test_the_raster_drawn_frame_by_frame_shows_every_spike_kept_and_nothing_stale(
    tmp_path, chromium
):
    """The raster draws each spike once, onto a ring of columns, and copies the ring each
    frame: after playing past the raster's width (the ring has wrapped), and after a jump
    back (drawn anew), it shows exactly the spikes the page keeps."""
    from playwright.sync_api import sync_playwright

    # 8 s, a spike and a pulse every 10 ms; the spikes' channels repeat every 280 ms, so
    # what a column held 3 s before differs from what it holds now
    write_run(tmp_path / "run", steps=800, spike_channel=lambda k: (k // 7) % 4)
    port = free_tcp_port()
    replay = subprocess.Popen(
        [sys.executable, "-m", "hub.cli", "dashboard", "--replay", str(tmp_path / "run")]
        + ["--speed", "2", "--port", str(port)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        cwd=ROOT,
    )
    checks = {}
    try:
        _serving(f"http://127.0.0.1:{port}/", replay)
        with sync_playwright() as pw:
            errors: list[str] = []
            browser, page = _open_page(pw, chromium, port, errors)
            page.wait_for_function("nv.replay && nv.t_s > 5.0", timeout=TIMEOUT_MS)
            page.click("#btn-play")  # pause: the page then draws the same time frame after frame
            page.wait_for_function("nv.replay && !nv.replay.playing", timeout=TIMEOUT_MS)
            drawn = page.evaluate("nv.stats.drawn")
            page.wait_for_function(f"nv.stats.drawn > {drawn + 3}", timeout=TIMEOUT_MS)
            checks["after playing"] = page.evaluate(RASTER_AGAINST_SPIKES)
            page.eval_on_selector(
                "#slider", "(el) => { el.value = 3.5; el.dispatchEvent(new Event('change')); }"
            )
            page.wait_for_function("Math.abs(nv.t_s - 3.5) < 0.05", timeout=TIMEOUT_MS)
            drawn = page.evaluate("nv.stats.drawn")
            page.wait_for_function(f"nv.stats.drawn > {drawn + 3}", timeout=TIMEOUT_MS)
            checks["after a jump back"] = page.evaluate(RASTER_AGAINST_SPIKES)
            browser.close()
    finally:
        _stop(replay)
    assert errors == []
    for when, got in checks.items():
        # a 3 s window of a spike every 10 ms, less the step without one
        assert got["shown"] >= 290, (when, got)
        assert got["nWrong"] == 0 and got["nStray"] == 0, (when, got)
