"""A Khepera III: its dialect through a real pseudo-terminal, its units, its body and a run.

The Khepera III's facts are K-Team's user manual (v2.2): ``D`` speeds in units of
1/144.01 mm/s, position counters set with ``I`` and read with ``R`` in pulses of 0.047 mm,
``N`` answering 9 IR values around the body, 2 on the ground and a time stamp. No IR
calibration is published, so these tests write a table of their own (``TABLE``: invented
for the test, not a measured curve) and give it to both the emulator and the adapter.
"""

from __future__ import annotations

import math
import subprocess
import sys
import time

import numpy as np
import pytest

from adapters.khepera.emulator import KheperaEmulator
from adapters.khepera.endpoint import KheperaEndpoint
from adapters.khepera.protocol import ReplyError
from devices import khepera
from hub import conformance
from hub.config import load_config
from hub.protocol import SensorReading
from hub.record import read_run
from tests.adapters.khepera_rig import (
    check_odometry_follows_an_arc,
    frozen_heap,
    make_driver,
    make_endpoint,
    open_link,
)

#: (distance_m, value): an IR response for these tests only, over the sensors' 0.02-0.2 m
TABLE = np.array(
    [(0.02, 1000.0), (0.04, 600.0), (0.06, 380.0), (0.1, 180.0), (0.15, 80.0), (0.2, 30.0)]
)
K3 = khepera.MODELS["khepera3"]


@pytest.fixture
def emulator():
    with KheperaEmulator(dialect="khepera3", ir_table=TABLE) as emu:
        yield emu


@pytest.fixture
def table_file(tmp_path):
    path = tmp_path / "k3_ir.csv"
    path.write_text("distance_m,value\n" + "".join(f"{d},{v}\n" for d, v in TABLE))
    return path


def test_every_command_of_the_khepera3_dialect_gets_its_reply_parsed(emulator):
    link = open_link(emulator, baud=115200)
    assert link.transact("B").fields[0].startswith("nv-emulator")
    assert link.transact("D", 20000, -20000).fields == ()
    assert emulator.commands[-1][1] == b"D,l20000,l-20000"  # typed integers on the way out
    assert link.transact("E").fields == (20000, -20000)
    assert link.transact("I", 100, 200).fields == ()
    left, right = link.transact("R").fields
    assert left >= 100 and right <= 200  # counting on from where they were set
    n = link.transact("N").fields
    assert len(n) == 12 and n[9:11] == (600, 600)  # 9 around, 2 ground, a time stamp
    assert link.transact("N").fields[11] >= n[11]
    assert len(link.transact("O").fields) == 12
    with pytest.raises(ReplyError, match="refused"):
        link.transact("H")  # a Khepera II's counter read: not this robot's
    link.transact("D", 0, 0)


def test_a_straight_run_of_known_speed_and_time_covers_the_expected_distance(emulator):
    link = open_link(emulator, baud=115200)
    link.transact("I", 0, 0)
    link.transact("D", 14401, 14401)  # 14,401 units = 100 mm/s
    t0 = time.monotonic()
    while time.monotonic() - t0 < 1.0:
        link.transact("N")
    link.transact("D", 0, 0)
    elapsed_s = time.monotonic() - t0
    left, right = link.transact("R").fields
    for pulses in (left, right):
        assert pulses * 0.047e-3 == pytest.approx(0.1 * elapsed_s, rel=0.05)


def test_speeds_become_khepera3_units_clamped_at_its_regulated_top_speed(emulator):
    driver = make_driver(emulator, baud=115200)
    assert driver.units.to_units(0.1) == (14401, False)
    assert driver.units.to_units(0.5) == (43000, True)  # 298 mm/s at most
    assert driver.units.max_mps == pytest.approx(0.2986, abs=1e-4)
    driver.link.close()


def test_ir_values_become_the_true_distance_through_the_labs_table(emulator):
    # The robot 50 mm (front sensors) from the arena's wall, facing it.
    emulator.arena.reset((0.0, -0.5 + 0.066 + 0.05, -math.pi / 2))
    driver = make_driver(emulator, baud=115200)
    driver.connect()
    try:
        true_m = emulator.arena.read_sensors()
        ranges = driver.latest().ranges_m
        seen = true_m < 0.2
        assert seen[[3, 4]].all()  # front left, front right
        np.testing.assert_allclose(ranges[seen], true_m[seen], atol=0.002)
        np.testing.assert_allclose(ranges[~seen], 0.2, rtol=1e-6)
    finally:
        driver.close()


def test_odometry_follows_the_emulated_khepera3(emulator):
    check_odometry_follows_an_arc(emulator, baud=115200)


def test_the_khepera3_endpoint_describes_its_body(emulator):
    endpoint = make_endpoint(emulator, baud=115200)
    try:
        d = endpoint.describe()
        assert d.n_sensors == 9 and d.wheel_base_m == pytest.approx(0.0885)
        np.testing.assert_allclose(d.sensor_angles_rad, np.radians(K3.sensor_facings_deg))
        assert d.max_range_m == pytest.approx(0.2) and d.max_wheel_mps == pytest.approx(
            0.2986, 1e-3
        )
        assert d.radius_m == pytest.approx(0.064)
    finally:
        endpoint.close()


@pytest.mark.parametrize("check", conformance.CHECKS, ids=lambda c: c.__name__)
def test_the_khepera3_endpoint_keeps_the_contract(check):
    emulators = []

    def new():
        emulators.append(KheperaEmulator(dialect="khepera3", ir_table=TABLE).start())
        return make_endpoint(emulators[-1], baud=115200, watchdog_s=5.0)

    try:
        check(new)
    finally:
        for emu in emulators:
            emu.stop()


def test_a_khepera3_body_takes_its_models_serial_settings_and_the_labs_table(table_file):
    body = f'{{port = "/dev/null", dialect = "khepera3", ir_table_file = "{table_file}"}}'
    cfg = load_config("configs/hybrid_khepera.toml", [f"body.params={body}"])
    params = KheperaEndpoint.check_config(cfg.body, cfg)
    assert (params["baud"], params["stop_bits"]) == (115200, 1)  # the robot's 8N1


def test_the_emulator_of_a_khepera3_needs_an_ir_table():
    with pytest.raises(ValueError, match="no published IR response"):
        KheperaEmulator(dialect="khepera3")
    done = subprocess.run(
        [sys.executable, "-m", "hub.cli", "emulate", "khepera", "--dialect", "khepera3"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 3 and "--ir-table" in done.stderr


@pytest.mark.bus
@pytest.mark.slow  # the dialect is checked above; this adds a whole run (the default run's margin)
def test_a_short_hybrid_run_with_a_khepera3(tmp_path, bus_overrides, table_file):
    emulated = KheperaEmulator(dialect="khepera3", ir_table=TABLE, baud=115200, stop_bits=1)
    with frozen_heap(), emulated as emu:
        sets = [*bus_overrides, f'body.params.port="{emu.path}"', 'body.params.dialect="khepera3"',
                f'body.params.ir_table_file="{table_file}"', "body.params.baud=115200",
                'body.params.world="configs/worlds/khepera3.toml"',
                "loop.period_ms=10.0"]  # fmt: skip
        args = [sys.executable, "-m", "hub.cli", "run", "configs/hybrid_khepera.toml", "--quiet"]
        args += ["--duration-s", "3", "--runs-dir", str(tmp_path / "runs")]
        for item in sets:
            args += ["--set", item]
        done = subprocess.run(args, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr[-2000:]
        assert emu.commands[-1][1] == b"D,l0,l0"  # stopped at the end
    (run_dir,) = (tmp_path / "runs").iterdir()
    record = read_run(run_dir)
    readings = record.decoded(SensorReading, "rx")
    assert len(readings) >= 290 and all(r.ranges_m.size == 9 for r in readings)
    body = record.manifest["endpoints"]["body"]
    assert body["kind"] == "khepera" and body["device"]["replies"] > 100
