"""The Khepera protocol as bytes: commands made, replies checked before they are data."""

from __future__ import annotations

import numpy as np
import pytest

from adapters.khepera.calibration import IRCalibration, Odometry
from adapters.khepera.driver import WheelUnits
from adapters.khepera.protocol import (
    UNKNOWN_COMMAND_REPLY,
    ReplyError,
    command,
    parse_command,
    parse_reply,
)
from devices import khepera
from hub.config import ConfigError


def test_commands_are_ascii_lines_ending_in_a_carriage_return():
    assert command("D", 10, -10) == b"D,10,-10\r"
    assert command("N") == b"N\r"
    assert command("d", 1, 2, dialect="khepera3") == b"D,l1,l2\r"


def test_a_reply_is_parsed_only_when_it_is_complete_and_is_the_one_awaited():
    assert parse_reply("N", b"n,1,2,3,4,5,6,7,1023\r\n").fields == (1, 2, 3, 4, 5, 6, 7, 1023)
    assert parse_reply("D", b"d\r\n").fields == ()
    assert parse_reply("H", b"h,-5,123456\r\n").fields == (-5, 123456)
    assert parse_reply("B", b"b,5.02,6.00\r\n").fields == ("5.02", "6.00")


@pytest.mark.parametrize(
    "letter, line, kind",
    [
        ("N", b"n,1,2,3", "truncated"),  # cut short: no line end
        ("N", b"", "truncated"),  # nothing came
        ("N", b"\x8f#\xfen,1,2,3,4,5,6,7,8\r\n", "garbled"),  # bytes before the reply
        ("N", b"n,1,2,3,4,5,6,7\r\n", "garbled"),  # a value missing
        ("N", b"n,1,2,x,4,5,6,7,8\r\n", "garbled"),  # not a number
        ("H", b"d\r\n", "order"),  # a late reply to an earlier D
        ("H", b"H,1,2\r\n", "garbled"),  # an echo, not a reply
        ("Z", UNKNOWN_COMMAND_REPLY, "refused"),
    ],
)
def test_a_bad_reply_line_is_named_and_keeps_its_bytes(letter, line, kind):
    with pytest.raises(ReplyError) as caught:
        parse_reply(letter, line)
    assert caught.value.kind == kind and caught.value.line == line


def test_the_emulator_reads_commands_of_both_dialects():
    assert parse_command(b"D,10,-3") == ("D", (10, -3))
    assert parse_command(b"d,l10,l-3") == ("D", (10, -3))
    with pytest.raises(ValueError):
        parse_command(b"hello")


def test_speeds_become_the_robots_units_clamped_to_its_limit():
    units = WheelUnits(khepera.KHEPERA2_SPEED_UNIT_MPS, khepera.KHEPERA2_MAX_SPEED_UNITS)
    assert units.to_units(0.08) == (10, False)  # 8 mm/s per unit
    assert units.to_units(-0.0041) == (-1, False)
    assert units.to_units(2.0) == (127, True)
    assert units.max_mps == pytest.approx(1.016)


def test_ir_values_become_distances_through_the_published_table():
    cal = IRCalibration.published()
    values = [1023, 1000, 450, 275, 150, 100, 80, 79, 0]
    expected = [0.008, 0.010, 0.020, 0.030, 0.050, 0.080, 0.100, 0.100, 0.100]
    np.testing.assert_allclose(cal.range_m(values), expected, atol=1e-6)
    assert cal.range_m([725])[0] == pytest.approx(0.015, abs=1e-6)  # halfway 1000..450
    assert cal.max_range_m == pytest.approx(0.100)


def test_a_labs_own_table_is_read_from_csv_and_a_bad_one_is_named(tmp_path):
    good = tmp_path / "ir.csv"
    good.write_text("distance_m,value\n0.01,900\n0.05,300\n0.12,20\n")
    cal = IRCalibration.from_file(good)
    assert cal.range_m([300])[0] == pytest.approx(0.05) and cal.max_range_m == 0.12
    bad = tmp_path / "bad.csv"
    bad.write_text("distance_m,value\n0.01,100\n0.05,300\n")  # rising with distance
    with pytest.raises(ConfigError, match="body.params.ir_table_file.*decrease"):
        IRCalibration.from_file(bad)


def test_odometry_follows_straight_runs_and_turns_on_the_spot():
    odo = Odometry(khepera.KHEPERA2_PULSE_M, khepera.KHEPERA2_WHEEL_BASE_M)
    odo.reset((0.0, 0.0, 0.0), (0, 0))
    np.testing.assert_allclose(odo.update((1000, 1000)), [0.08, 0.0, 0.0], atol=1e-12)
    quarter = np.pi / 2 * khepera.KHEPERA2_WHEEL_BASE_M / 2 / khepera.KHEPERA2_PULSE_M
    pose = odo.update((1000 - quarter, 1000 + quarter))
    np.testing.assert_allclose(pose, [0.08, 0.0, np.pi / 2], atol=1e-9)
