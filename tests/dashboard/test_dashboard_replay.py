"""The replay of a recorded run: the same state as live, at any speed, with jumps."""

from __future__ import annotations

import base64

import numpy as np
import pytest

from dashboard.replay import ReplayError, ReplaySource
from dashboard.state import FrameState, Reader
from hub.record import read_run, write_manifest
from tests.dashboard.synthetic import BURST, N_STEPS, pose, write_run


@pytest.fixture
def run_dir(tmp_path):
    path = tmp_path / "run"
    write_run(path)
    return path


def _replay(run_dir, speed=1.0):
    state = FrameState()
    source = ReplaySource(run_dir, state, speed=speed)
    source.start()
    source.page_opened()
    return source, state


def _advance(source, wall_s):
    """As if ``wall_s`` of wall time had passed since the last tick."""
    with source.state.lock:
        source.tick(now=source._wall + wall_s)


def test_the_scene_is_the_runs_world_body_and_culture(run_dir):
    source, state = _replay(run_dir)
    scene = state.scene
    assert scene["arena"] == {"shape": "circle", "radius_m": 0.5}  # the default world
    assert len(scene["obstacles"]) == 3
    assert scene["body"]["sensor_angles_rad"] == [-0.5, 0.0, 0.5]
    assert scene["culture"]["channel"] == [0, 1, 2, 3]
    assert (scene["period_ms"], scene["mode"], scene["n_steps"]) == (10.0, "lockstep", N_STEPS)
    assert source.duration_s == pytest.approx(2.0)


def test_playing_feeds_what_happened_in_run_time_at_the_speed_asked(run_dir):
    source, state = _replay(run_dir, speed=10.0)
    _advance(source, 0.0504)  # 0.504 s of the run
    frame = state.frame(Reader())
    assert source.t_s == pytest.approx(0.504)
    assert frame["step"] == 49 and frame["pose"] == pose(49)
    assert frame["replay"]["playing"] and frame["replay"]["t_s"] == pytest.approx(0.504)
    assert frame["spikes"]["n"] == 50  # one a step, those of [0, 0.5 s)
    assert [r[0] for r in frame["rates"]] == pytest.approx([0.05 * b for b in range(1, 11)])
    assert frame["status"]["late"] == {} and frame["status"]["state"] == "replay"


def test_a_jump_gives_the_state_the_history_a_page_shows_then(run_dir):
    source, state = _replay(run_dir)
    reader = Reader()
    state.frame(reader)
    reply = source.command({"cmd": "seek", "t_s": 1.0})
    assert reply["ok"]
    frame = state.frame(reader)
    assert frame["reset"] and frame["step"] == 99 and frame["pose"] == pose(99)
    assert frame["trail"][0] == [0.0, 0.0] and frame["trail"][-1] == pytest.approx([0.098, 0.0])
    t = np.frombuffer(base64.b64decode(frame["spikes"]["t"]), "<f4") + frame["spikes"]["t0"]
    assert t.size == 99 and t.max() == pytest.approx(995.0)  # step 70's is missing
    assert frame["bursts"] == [[500.0, 560.0, 3, 520.0, 530.0]]
    # what the hub noted up to 1 s: the late body reply of step 50, the missing one of 70
    assert frame["status"]["late"] == {"body": 1} and frame["status"]["missing"] == {"culture": 1}
    assert frame["status"]["dropped"] == {"body": 2}  # the run's, from the manifest
    assert frame["endpoints"]["body"]["counters"]["steps"] == N_STEPS


def _pulse_times_ms(frame) -> np.ndarray:
    pulses = frame["pulses"]
    return np.frombuffer(base64.b64decode(pulses["t"]), "<f4") + pulses["t0"]


def test_a_pulse_at_the_time_jumped_to_is_shown_once(run_dir):
    source, state = _replay(run_dir)
    reader = Reader()
    state.frame(reader)
    assert source.command({"cmd": "seek", "t_s": 1.0})["ok"]  # step 100's pulse: 1000 ms
    shown = list(_pulse_times_ms(state.frame(reader)))
    # past 1.05 s of run time whatever the monotonic clock reads (at 1,164 s since boot,
    # wall + 0.05 - wall is 0.04999999999995)
    _advance(source, 0.06)
    shown += list(_pulse_times_ms(state.frame(reader)))
    assert shown.count(1000.0) == 1 and 1050.0 in shown


def test_a_network_burst_shows_once_its_core_ended_though_its_extent_lasts_to_the_end(tmp_path):
    """In a closed loop a stimulated channel's burst may hold a network burst's extent open
    to the end of the run: the replay shows it when its core has ended, as the run's
    detector knew it, with the extent as recorded."""
    long = {**BURST, "end_ms": 2000.0}
    write_run(tmp_path / "run", bursts=(long,))
    source, state = _replay(tmp_path / "run", speed=10.0)
    reader = Reader()
    _advance(source, 0.052)  # to 0.52 s: the core (520-530 ms) is not over
    assert state.frame(reader)["bursts"] == []
    _advance(source, 0.002)  # to 0.54 s
    assert state.frame(reader)["bursts"] == [[500.0, 2000.0, 3, 520.0, 530.0]]
    source.command({"cmd": "seek", "t_s": 0.6})
    assert state.frame(reader)["bursts"] == [[500.0, 2000.0, 3, 520.0, 530.0]]


def test_the_replay_stops_at_the_end_and_plays_again_from_the_start(run_dir):
    source, state = _replay(run_dir, speed=50.0)
    _advance(source, 10.0)
    assert source.t_s == pytest.approx(2.0) and not source.playing
    assert state.step == N_STEPS - 1 and state.status["state"] == "replay paused"
    assert source.command({"cmd": "play"})["ok"]
    assert source.t_s == 0.0 and source.playing


def test_the_replay_waits_for_its_first_page(run_dir):
    state = FrameState()
    source = ReplaySource(run_dir, state, speed=10.0)
    source.start()
    _advance(source, 1.0)
    assert source.t_s == 0.0 and state.status["state"] == "replay paused"
    source.page_opened()
    _advance(source, 0.01)
    source.page_opened()  # a second page changes nothing
    _advance(source, 0.01)
    assert source.t_s == pytest.approx(0.2) and source.playing


def test_pause_speed_and_bad_commands(run_dir):
    source, state = _replay(run_dir)
    assert source.command({"cmd": "pause"})["state"] == "replay paused"
    _advance(source, 1.0)
    assert source.t_s == 0.0
    assert source.command({"cmd": "speed", "x": 4})["ok"] and source.speed == 4.0
    for bad in (0, float("inf"), float("nan"), 5000):  # inf showed as "null×" on the page
        assert not source.command({"cmd": "speed", "x": bad})["ok"]
    assert source.speed == 4.0
    with pytest.raises(ReplayError, match="the speed must be 0.01 to 1000"):
        ReplaySource(run_dir, FrameState(), speed=float("inf"))
    assert not source.command({"cmd": "seek"})["ok"]
    assert not source.command({"cmd": "stop"})["ok"]  # a replay has no run to stop


def test_the_trajectory_replayed_is_the_records(run_dir):
    source, state = _replay(run_dir, speed=3.0)
    seen = {}
    while source.playing:
        _advance(source, 0.02)
        frame = state.frame(Reader())
        seen[frame["step"]] = frame["pose"]
    t_s, poses = read_run(run_dir).trajectory()
    assert len(seen) > 20
    for step, p in seen.items():
        assert p == poses[step].tolist()


def test_a_folder_without_readings_cannot_be_replayed(tmp_path):
    write_manifest(tmp_path, {"format": "neuvision-run", "outcome": "fault"})
    with pytest.raises(ReplayError, match="no body reading"):
        ReplaySource(tmp_path, FrameState())
