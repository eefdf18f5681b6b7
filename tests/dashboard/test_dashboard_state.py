"""The dashboard's frame state: histories by run time, read by cursor; no bus, no web."""

from __future__ import annotations

import base64
import json

import numpy as np
import pytest

from dashboard.state import (
    ACTIVITY_TAU_MS,
    BIN_MS,
    LIT_MS,
    MAX_SPIKES_PER_FRAME,
    RASTER_S,
    TRAIL_STEP_M,
    FrameState,
    Reader,
    Tape,
)

# four channels: ids 10, 11 excitatory, 12, 13 inhibitory, on a line 100 um apart
CULTURE = {
    "id": "0",
    "kind": "test",
    "channel": [10, 11, 12, 13],
    "x_um": [0.0, 100.0, 200.0, 300.0],
    "y_um": [0.0, 0.0, 0.0, 0.0],
    "cell_type": [0, 0, 1, 1],
}


def _state() -> FrameState:
    state = FrameState()
    state.set_scene({"name": "t", "culture": CULTURE})
    return state


def _events(stream: dict) -> tuple[np.ndarray, np.ndarray]:
    """A frame's (times ms, channel indices), decoded as the page does."""
    if not stream["n"]:
        return np.zeros(0), np.zeros(0, np.int64)
    t = np.frombuffer(base64.b64decode(stream["t"]), "<f4") + stream["t0"]
    return t, np.frombuffer(base64.b64decode(stream["i"]), f"<u{stream['i_bytes']}")


def test_a_tape_gives_each_reader_what_came_after_its_cursor_while_it_is_kept():
    tape = Tape(keep_s=1.0)
    for k in range(5):
        tape.add(k * 0.5, k)
    assert tape.since(0) == [0, 1, 2, 3, 4] and tape.since(3) == [3, 4] and tape.since(5) == []
    tape.trim(now_s=2.0)  # keeps t >= 1.0
    assert tape.since(0) == [2, 3, 4] and tape.since(4) == [4] and len(tape) == 3


def test_rates_and_the_center_of_activity_per_bin_whatever_the_batches():
    # 100 ms: in the first bin channel 10 fires 4 times and channel 13 twice, in the second
    # channel 11 fires 5 times
    channel = np.array([10, 10, 13, 10, 10, 13, 11, 11, 11, 11, 11])
    t_ms = np.array([1, 5, 9, 12, 30, 31, 55, 60, 70, 80, 99.0])
    one = _state()
    one.add_spikes(channel, t_ms, 0.0, 100.0)
    steps = _state()  # the same spikes in 10 ms steps, as a live run gives them
    for k in range(10):
        sel = (t_ms >= 10 * k) & (t_ms < 10 * (k + 1))
        steps.add_spikes(channel[sel], t_ms[sel], 10.0 * k, 10.0 * (k + 1))
    for state in (one, steps):
        frame = state.frame(Reader())
        to_hz = 1e3 / BIN_MS
        assert frame["rates"] == [
            [0.05, 6 / 4 * to_hz, 4 / 2 * to_hz, 2 / 2 * to_hz],
            [0.1, 5 / 4 * to_hz, 5 / 2 * to_hz, 0.0],
        ]
        assert frame["ca"] == [[0.05, 100.0, 0.0], [0.1, 100.0, 0.0]]
        assert frame["t_s"] == 0.1


def test_a_large_culture_over_many_bins_gets_the_same_rates_and_center_of_activity(
    monkeypatch,
):
    """Past COUNT_MATRIX_MAX bins x channels the sums are taken another way: the same."""
    rng = np.random.default_rng(3)
    channel = rng.choice(CULTURE["channel"], 500)
    t_ms = np.sort(rng.uniform(0.0, 1000.0, 500))

    def shown():
        state = _state()
        state.add_spikes(channel, t_ms, 0.0, 1000.0)
        frame = state.frame(Reader())
        return frame["rates"], frame["ca"]

    through_the_matrix = shown()
    monkeypatch.setattr("dashboard.state.COUNT_MATRIX_MAX", 0)
    assert shown() == through_the_matrix
    assert len(through_the_matrix[0]) == 20  # every 50 ms bin of the second


def test_a_bin_covered_less_than_half_is_left_out_not_shown_as_silence():
    state = _state()
    state.add_spikes([10], [5.0], 0.0, 20.0)  # the first 20 ms of the first bin only
    state.add_spikes([10], [60.0], 50.0, 100.0)  # all of the second
    rates = state.frame(Reader())["rates"]
    assert [r[0] for r in rates] == [0.1]


def test_a_late_reply_for_a_bin_already_shown_is_not_counted_again():
    state = _state()
    state.add_spikes([10, 10], [10.0, 20.0], 0.0, 60.0)
    reader = Reader()
    assert len(state.frame(reader)["rates"]) == 1
    state.add_spikes([10, 10, 10], [1.0, 2.0, 3.0], 0.0, 10.0)  # late: bin 0 is closed
    state.add_spikes([], [], 60.0, 100.0)
    (second,) = state.frame(reader)["rates"]
    assert second[0] == 0.1 and second[1] == 0.0


def test_each_page_gets_every_spike_once_and_a_new_page_all_that_is_kept():
    state = _state()
    first = Reader()
    state.add_spikes([10, 12], [1.0, 2.0], 0.0, 10.0)
    t, i = _events(state.frame(first)["spikes"])
    assert t.tolist() == [1.0, 2.0] and i.tolist() == [0, 2]
    state.add_spikes([13], [15.5], 10.0, 20.0)
    frame = state.frame(first)
    assert not frame["reset"] and _events(frame["spikes"])[1].tolist() == [3]
    assert state.frame(first)["spikes"]["n"] == 0  # nothing new
    late = Reader()
    frame = state.frame(late)
    assert frame["reset"] and _events(frame["spikes"])[1].tolist() == [0, 2, 3]


def test_channel_indices_go_as_two_bytes_up_to_65536_channels_and_as_four_past_it():
    for n_channels, width in ((1 << 16, 2), ((1 << 16) + 1, 4)):
        state = FrameState()
        ids = list(range(n_channels))
        zeros = [0.0] * n_channels
        state.set_scene({"name": "t", "culture": {**CULTURE, "channel": ids, "x_um": zeros,
                                                   "y_um": zeros, "cell_type": None}})  # fmt: skip
        state.add_spikes([0, n_channels - 1], [1.0, 2.0], 0.0, 10.0)
        spikes = state.frame(Reader())["spikes"]
        assert spikes["i_bytes"] == width
        assert _events(spikes)[1].tolist() == [0, n_channels - 1]


def test_a_frame_over_the_cap_carries_the_newest_and_says_from_when():
    """A page that fell behind gets the newest MAX_SPIKES_PER_FRAME spikes and the time
    before which some were left out (shown as not shown, never as silence); a page's first
    frame, as after a jump in a replay, gets the whole raster."""
    state = _state()
    reader = Reader()
    state.frame(reader)
    n = MAX_SPIKES_PER_FRAME + 500
    t_ms = np.linspace(0.0, 999.0, n)
    state.add_spikes(np.full(n, 10), t_ms, 0.0, 1000.0)
    spikes = state.frame(reader)["spikes"]
    assert spikes["n"] == MAX_SPIKES_PER_FRAME
    assert spikes["capped_before_ms"] == pytest.approx(t_ms[500])
    first = state.frame(Reader())["spikes"]
    assert first["n"] == n and "capped_before_ms" not in first


def test_spikes_older_than_the_raster_are_let_go_and_unknown_channels_ignored():
    state = _state()
    state.add_spikes([10, 99], [1.0, 2.0], 0.0, 10.0)
    state.add_spikes([11], [RASTER_S * 1e3 + 500.0], RASTER_S * 1e3, RASTER_S * 1e3 + 510)
    t, i = _events(state.frame(Reader())["spikes"])
    assert i.tolist() == [1]


def test_a_reset_starts_every_history_again_and_tells_the_page():
    state = _state()
    reader = Reader()
    state.add_spikes([10], [1.0], 0.0, 60.0)
    state.add_sensors(5, 0.06, [0.1, 0.2, 0.0], [0.25], False)
    state.frame(reader)
    state.reset()
    frame = state.frame(reader)
    assert frame["reset"] and frame["trail"] == [] and frame["spikes"]["n"] == 0
    assert frame["step"] == -1 and frame["pose"] is None


def test_the_newest_reading_wins_and_the_trail_keeps_a_point_per_few_millimetres():
    state = _state()
    for k in range(10):
        state.add_sensors(k, (k + 1) * 0.01, [k * TRAIL_STEP_M / 2, 0.0, 0.5], [0.2, 0.25], False)
    state.add_sensors(3, 0.04, [9.0, 9.0, 0.0], [0.1, 0.1], True)  # a late reading
    frame = state.frame(Reader())
    assert frame["step"] == 9 and frame["pose"] == [9 * TRAIL_STEP_M / 2, 0.0, 0.5]
    assert frame["ranges"] == [0.2, 0.25] and frame["contact"] is False
    xs = [p[0] for p in frame["trail"] if p[1] == 0.0]
    assert xs == pytest.approx([0.0, 0.002, 0.004, 0.006, 0.008])


def test_the_newest_motor_command_by_step_is_shown_whatever_the_order_it_came_in():
    state = _state()
    state.add_motor(7, 0.05, 0.04)
    state.add_motor(6, -0.1, -0.1)  # a command of an earlier step, come late
    assert state.frame(Reader())["motor"] == [0.05, 0.04]
    state.add_motor(8, 0.0, 0.0)
    assert state.frame(Reader())["motor"] == [0.0, 0.0]
    state.reset()  # a jump back in a replay: the step order starts again
    state.add_motor(2, 0.01, 0.02)
    assert state.frame(Reader())["motor"] == [0.01, 0.02]


def test_sites_stay_lit_for_a_while_after_their_pulse():
    state = _state()
    state.add_pulses([11, 13, 77], [100.0, 100.0, 100.0])
    state.add_spikes([], [], 100.0, 100.0 + LIT_MS / 2)
    assert state.frame(Reader())["lit"] == [1, 3]
    state.add_spikes([], [], 100.0 + LIT_MS / 2, 100.0 + 2 * LIT_MS)
    assert state.frame(Reader())["lit"] == []


def test_a_channels_activity_fades_with_time():
    state = _state()
    state.add_spikes([12, 12, 12], [1.0, 2.0, 3.0], 0.0, 10.0)
    level = lambda: np.frombuffer(base64.b64decode(state.frame(Reader())["activity"]), np.uint8)  # noqa: E731
    now = level()
    assert now[2] > 200 and now[[0, 1, 3]].tolist() == [0, 0, 0]
    state.add_spikes([], [], 10.0, 10.0 + 5 * ACTIVITY_TAU_MS)
    assert level()[2] < 10


def test_network_bursts_are_kept_once_however_often_the_hub_repeats_them():
    state = _state()
    state.add_bursts([[100.0, 180.0, 3, 120.0, 130.0], [400.0, 450.0, 4, 410.0, 420.0]])
    state.add_bursts([[400.0, 450.0, 4, 410.0, 420.0], [900.0, 990.0, 2, 930.0, 935.0]])
    assert state.frame(Reader())["bursts"] == [
        [100.0, 180.0, 3, 120.0, 130.0],
        [400.0, 450.0, 4, 410.0, 420.0],
        [900.0, 990.0, 2, 930.0, 935.0],
    ]


def test_network_bursts_whose_extents_share_a_long_burst_are_each_kept():
    """In a closed loop a stimulated channel bursts for seconds: two network bursts it takes
    part in have the same extent, and are told apart by their cores."""
    state = _state()
    state.add_bursts([[10.0, 9000.0, 5, 100.0, 110.0], [10.0, 9000.0, 6, 3000.0, 3008.0]])
    assert [b[3] for b in state.frame(Reader())["bursts"]] == [100.0, 3000.0]


def test_a_network_burst_without_a_core_is_shown_by_its_extent():
    state = _state()
    state.add_bursts([[500.0, 560.0, 3]])
    assert state.frame(Reader())["bursts"] == [[500.0, 560.0, 3, 500.0, 560.0]]


def test_a_frame_is_plain_json():
    state = _state()
    state.add_spikes([10], [1.0], 0.0, 60.0)
    state.add_sensors(0, 0.01, np.array([0.0, 0.0, 0.0]), np.array([0.2], np.float32), False)
    state.set_status({"state": "running", "step": 1})
    json.dumps(state.frame(Reader()), allow_nan=False)


def test_before_a_scene_spikes_are_not_kept():
    state = FrameState()
    state.add_spikes([1], [1.0], 0.0, 10.0)
    assert state.frame(Reader())["spikes"]["n"] == 0
