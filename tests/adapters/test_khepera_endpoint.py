"""The Khepera endpoint keeps the contract, and refuses what a real robot cannot do."""

from __future__ import annotations

import pytest

from adapters.khepera.emulator import KheperaEmulator
from adapters.khepera.endpoint import KheperaEndpoint
from adapters.khepera.link import LinkFault
from hub import conformance
from hub.config import ConfigError, load_config
from tests.adapters.khepera_rig import make_endpoint

HYBRID = "configs/hybrid_khepera.toml"


@pytest.fixture
def emulators():
    started: list[KheperaEmulator] = []

    def new() -> KheperaEmulator:
        started.append(KheperaEmulator().start())
        return started[-1]

    yield new
    for emulator in started:
        emulator.stop()


@pytest.mark.parametrize("check", conformance.CHECKS, ids=lambda c: c.__name__)
def test_the_khepera_endpoint_keeps_the_contract(check, emulators):
    check(lambda: make_endpoint(emulators(), watchdog_s=5.0))


def test_it_describes_the_real_robot_and_its_measured_serial_cycle(emulators):
    endpoint = make_endpoint(emulators())
    try:
        d = endpoint.describe()
        assert d.kind == "khepera" and d.realtime_only
        assert d.n_sensors == 8 and d.wheel_base_m == pytest.approx(0.053)
        assert d.max_range_m == pytest.approx(0.1) and d.max_wheel_mps == pytest.approx(1.016)
        assert d.cycle_ms > 0
    finally:
        endpoint.close()


def test_a_run_whose_period_does_not_suit_the_watchdog_is_refused(emulators):
    """The hub's period is announced with the run: an adapter started with another
    experiment file checks its watchdog against that period, not its own file's."""
    with conformance.served(lambda: make_endpoint(emulators(), watchdog_s=0.5)) as hub:
        reply = hub.start(period_ms=400.0, deadline_ms=400.0)
        assert not reply.ok
        assert "watchdog_s 0.5 s is under two loop periods (0.8 s)" in reply.reason
        assert "the run's period is 400 ms" in reply.reason
        assert hub.start(period_ms=50.0, deadline_ms=50.0).ok


def config(*overrides):
    return load_config(HYBRID, list(overrides))


def check(cfg):
    return KheperaEndpoint.check_config(cfg.body, cfg)


def test_a_lockstep_run_with_a_khepera_is_refused_before_it_starts():
    with pytest.raises(ConfigError, match=r"loop.mode: a Khepera is a real device.*realtime"):
        check(config('loop.mode="lockstep"'))


@pytest.mark.parametrize(
    "override, named",
    [
        ("body.params.baud=9601", "body.params.baud must be one of"),
        ("body.params.stop_bits=3", "body.params.stop_bits"),
        ("body.params.stop_bits=true", "body.params.stop_bits must be 1 or 2, got True"),
        ("body.params.watchdog_s=0", "body.params.watchdog_s"),
        # under two of the loop's 50 ms periods: stopped between steps, and its input
        # timeout (the same) made safe at nearly every step
        (
            "body.params.watchdog_s=0.08",
            r"body.params.watchdog_s 0.08 s is under two loop "
            r"periods \(0.1 s\)",
        ),  # fmt: skip
        # and the longest the robot drives on blind when its commands stop
        (
            "body.params.watchdog_s=60",
            r"body.params.watchdog_s 60 s: the robot would drive on that long .* at most 5 s",
        ),  # fmt: skip
        ("body.params.freeze_s=-1", "body.params.freeze_s"),
        # a failed reply and its retry are a live adapter's longest silence
        (
            "body.params.freeze_s=0.3",
            r"body.params.freeze_s 0.3 s is under two reply timeouts",
        ),  # fmt: skip
        ('body.params.dialect="khepera4"', r"dialect must be one of .*, got 'khepera4'"),
        ("body.params.start_pose=[0, 0]", "body.params.start_pose"),
        ('body.params.ir_table_file="nowhere.csv"', "body.params.ir_table_file"),
        ("body.params.speed=3", r"unknown key\(s\) \['speed'\]"),
        ('body.params.dialect="khepera4"', "body.params.dialect must be one of"),
        ('body.params.dialect="khepera3"', "body.params.ir_table_file: no IR calibration"),
        ('body.params.port=""', "body.params.port: the serial port of the robot is required"),
    ],
)
def test_bad_params_are_named_before_the_port_is_opened(override, named):
    with pytest.raises(ConfigError, match=named):
        check(config(override))


@pytest.mark.parametrize(
    "rows, named",
    [
        ("0.01,nan\n0.05,100\n", "must be numbers"),  # a gap in a lab's spreadsheet
        ("-0.05,1000\n0.05,100\n", "distances must be >= 0 m"),
    ],
)
def test_an_ir_table_with_a_gap_or_a_negative_distance_is_refused(tmp_path, rows, named):
    table = tmp_path / "ir.csv"
    table.write_text("distance_m,value\n" + rows)
    with pytest.raises(ConfigError, match=f"body.params.ir_table_file: {table}: .*{named}"):
        check(config(f'body.params.ir_table_file="{table}"'))


def test_the_hybrid_experiment_file_checks_out():
    params = check(config())
    assert params["port"] == "/tmp/neuvision-khepera" and params["baud"] == 9600
    assert params["freeze_s"] == 1.0  # the stop guard watches for a frozen adapter
    assert check(config("body.params.freeze_s=0"))["freeze_s"] == 0.0  # off, on purpose


def test_the_world_drawn_in_the_figures_must_exist():
    with pytest.raises(ConfigError, match="body.params.world: no world file"):
        check(config('body.params.world="nowhere.toml"'))


def test_a_freeze_limit_under_three_serial_cycles_is_refused_once_the_cycle_is_measured():
    """Shorter than three cycles of the serial thread, the stop guard would stop a live
    robot between its beats: refused at connect (when the cycle is known), naming the key."""
    with KheperaEmulator(baud=9600) as emulator:  # a cycle of ~60 ms: the bytes' time
        cfg = config(
            f'body.params.port="{emulator.path}"',
            "body.params.timeout_s=0.05",
            "body.params.freeze_s=0.1",
        )
        endpoint = KheperaEndpoint.from_config(cfg.body, cfg)
        try:
            with pytest.raises(
                ConfigError, match=r"body.params.freeze_s 0.1 s is under three serial"
            ):
                endpoint.warm_up()
        finally:
            endpoint.close()


def test_a_device_that_answers_but_not_as_the_robot_is_a_fault_naming_the_port():
    """Something on the port that answers, but not as this robot (here an emulator of the
    paper's 7-sensor robot, whose N reply has 7 fields; a modem, a robot at another baud):
    a device fault that says where and what, not a parsing error's traceback."""
    with KheperaEmulator("configs/worlds/paper.toml") as emulator:
        cfg = config(f'body.params.port="{emulator.path}"')  # configured as a Khepera II
        endpoint = KheperaEndpoint.from_config(cfg.body, cfg)
        try:
            with pytest.raises(LinkFault) as fault:
                endpoint.warm_up()
        finally:
            endpoint.close()
    message = str(fault.value)
    assert message.startswith(f"the device on {emulator.path} does not answer as a Khepera II")
    assert "body.params.baud" in message and "garbled: 7 fields" in message
