"""The wire contract: every message round-trips, and every kind of bad input is rejected."""

import dataclasses
import math
import threading

import msgpack
import numpy as np
import pytest
import zenoh
from hypothesis import example, given
from hypothesis import strategies as st

from hub.protocol import (
    SCHEMA_VERSION,
    SMALL_ARRAY,
    Array,
    ControlReply,
    ControlRequest,
    Description,
    HubStatus,
    Keys,
    MotorCommand,
    Potentials,
    ProtocolError,
    RunEnd,
    RunHold,
    RunStart,
    SensorReading,
    SpikeBatch,
    StepWindow,
    Stimulation,
    decode_run_request,
    merge_parts,
)

RUN = "0" * 32
PERIOD_S = 0.01
MOTOR_WINDOW = {"run": RUN, "t0_s": 0.0, "t1_s": PERIOD_S}


def W(step: int) -> StepWindow:
    """The window of ``step`` in the test run."""
    return StepWindow.of(RUN, step, PERIOD_S)


EXAMPLES = [
    MotorCommand(**W(4).stamp, left_mps=0.1, right_mps=-0.2, v_mps=-0.05, omega_rad_s=5.7),
    MotorCommand.stop(W(0)),
    SensorReading(
        step=7, run=RUN, t_s=0.07, ranges_m=[0.1, 0.3, 0.0], pose=[0.1, -0.2, 3.1], contact=True
    ),
    Stimulation(
        **W(2).stamp, channel=[3, 9], amplitude_ua=[50, 10], width_ms=[1, 10], onset_ms=[0, 2.5]
    ),
    Stimulation.none(W(0)),
    SpikeBatch(step=5, run=RUN, t0_s=0.05, t1_s=0.06, channel=[1, 1, 8], t_ms=[0.1, 2.0, 9.9]),
    Potentials(step=5, t_s=0.05, v_mv=[-65.0, -70.0]),
    Description(
        role="culture",
        id="0",
        kind="sim_network",
        channel=[0, 1, 2],
        x_um=[0, 50, 100],
        y_um=[0, 0, 0],
        cell_type=[0, 0, 1],
    ),
    Description(
        role="body",
        id="k2",
        kind="sim_robot",
        sensor_angles_rad=[-1.0, 0.0, 1.0],
        max_range_m=0.3,
        wheel_base_m=0.053,
        radius_m=0.035,
        max_wheel_mps=1.0,
    ),
    HubStatus(
        step=9,
        t_s=0.09,
        mode="realtime",
        state="running",
        late={"body": 1},
        missing={},
        dropped={"culture": 2},
        alive=["body/0", "culture/0"],
    ),
    ControlRequest(cmd="pause"),
    ControlReply(ok=True, state="paused", data={"step": 3}),
    RunHold(run=RUN, hold=True),
]


@pytest.mark.parametrize("message", EXAMPLES, ids=lambda m: type(m).__name__)
def test_every_message_round_trips(message):
    raw = message.encode()
    assert type(message).decode(raw) == message


def test_arrays_travel_as_little_endian_bin_of_the_schema_dtype():
    m = SensorReading(step=1, run=RUN, t_s=0.0, ranges_m=[0.25, 0.5], pose=[1, 2, 3], contact=False)
    data = msgpack.unpackb(m.encode(), raw=False)
    assert data["v"] == SCHEMA_VERSION
    assert data["ranges_m"] == np.array([0.25, 0.5], "<f4").tobytes()
    assert data["pose"] == np.array([1, 2, 3], "<f8").tobytes()


def _raw(**fields):
    base = {
        "v": SCHEMA_VERSION,
        "step": 3,
        "run": RUN,
        "t_s": 0.03,
        "ranges_m": np.array([0.1, 0.2], "<f4").tobytes(),
        "pose": np.zeros(3, "<f8").tobytes(),
        "contact": False,
    }
    base.update(fields)
    return msgpack.packb({k: v for k, v in base.items() if v is not ...}, use_bin_type=True)


@pytest.mark.parametrize(
    "raw, kind",
    [
        (b"\xc1\xc1garbage", "not_msgpack"),
        (msgpack.packb([1, 2, 3]), "not_a_map"),
        (_raw(v=1), "version"),
        (_raw(v=...), "version"),
        (_raw(step=...), "missing"),
        (_raw(extra=1), "unknown"),
        (_raw(step="3"), "type"),
        (_raw(step=-1), "range"),
        (_raw(step=1.5), "type"),
        (_raw(contact=1), "type"),
        (_raw(t_s=float("nan")), "non_finite"),
        (_raw(ranges_m=[0.1, 0.2]), "type"),
        (_raw(ranges_m=b"\x00\x00\x80"), "array"),
        (_raw(ranges_m=np.array([0.1, np.nan], "<f4").tobytes()), "non_finite"),
        (_raw(ranges_m=np.array([0.1, np.inf], "<f4").tobytes()), "non_finite"),
        (_raw(ranges_m=np.array([-0.1], "<f4").tobytes()), "range"),
        (_raw(pose=np.zeros(2, "<f8").tobytes()), "array"),
    ],
)
def test_malformed_sensor_readings_are_rejected_with_their_kind(raw, kind):
    with pytest.raises(ProtocolError) as err:
        SensorReading.decode(raw)
    assert err.value.kind == kind


def test_parallel_arrays_must_have_equal_lengths():
    with pytest.raises(ProtocolError, match="amplitude_ua has 1 values but channel has 2"):
        Stimulation(
            **W(1).stamp, channel=[1, 2], amplitude_ua=[5], width_ms=[1, 1], onset_ms=[0, 0]
        )


def test_spikes_must_be_sorted_and_inside_their_window():
    with pytest.raises(ProtocolError, match="sorted"):
        SpikeBatch(step=1, run=RUN, t0_s=0.01, t1_s=0.02, channel=[0, 1], t_ms=[5, 2])
    with pytest.raises(ProtocolError, match="beyond"):
        SpikeBatch(step=1, run=RUN, t0_s=0.01, t1_s=0.02, channel=[0], t_ms=[12.0])
    with pytest.raises(ProtocolError, match="precedes"):
        SpikeBatch(step=1, run=RUN, t0_s=0.02, t1_s=0.01)


def test_descriptions_need_their_role_geometry():
    with pytest.raises(ProtocolError, match="needs"):
        Description(role="body", id="0", kind="x", max_range_m=1.0)
    with pytest.raises(ProtocolError, match="unique"):
        Description(role="culture", id="0", kind="x", channel=[1, 1], x_um=[0, 0], y_um=[0, 0])
    with pytest.raises(ProtocolError, match="role"):
        Description(role="robot", id="0", kind="x")


def test_control_commands_are_a_closed_set():
    with pytest.raises(ProtocolError, match="cmd"):
        ControlRequest(cmd="explode")


def test_a_decoded_message_is_read_only():
    m = SensorReading.decode(EXAMPLES[2].encode())
    with pytest.raises(ValueError):
        m.ranges_m[0] = 1.0


def test_key_expressions_follow_the_architecture():
    k = Keys("lab1")
    assert k.motor("0") == "nv/lab1/body/0/motor"
    assert k.sensors("0") == "nv/lab1/body/0/sensors"
    assert k.stim("a") == "nv/lab1/culture/a/stim"
    assert k.spikes("a") == "nv/lab1/culture/a/spikes"
    assert k.potentials("a") == "nv/lab1/culture/a/potentials"
    assert k.describe("body", "0") == "nv/lab1/body/0/describe"
    assert k.hub_status == "nv/lab1/hub/status"
    assert k.hub_control == "nv/lab1/hub/control"
    assert k.alive("culture", "0") == "nv/lab1/alive/culture/0"
    assert k.parse_alive("nv/lab1/alive/culture/0") == ("culture", "0")
    assert k.parse_alive("nv/other/alive/culture/0") is None
    with pytest.raises(ValueError):
        Keys("a/b")


def test_one_key_expression_covers_every_endpoint_output():
    k = Keys("lab1")
    outputs = zenoh.KeyExpr(k.outputs_all)
    for key in (k.sensors("0"), k.spikes("0"), k.sensors("left"), k.spikes("mea2")):
        assert outputs.intersects(zenoh.KeyExpr(key))
    for key in (
        k.stim("0"),
        k.motor("0"),
        k.potentials("0"),
        k.hub_status,
        k.describe("body", "0"),
    ):
        assert not outputs.intersects(zenoh.KeyExpr(key))
    assert not outputs.intersects(zenoh.KeyExpr(Keys("lab2").spikes("0")))


finite = st.floats(allow_nan=False, allow_infinity=False, width=32)


@given(
    step=st.integers(0, 2**40),
    ranges=st.lists(st.floats(0, 10, width=32), max_size=32),
    pose=st.tuples(finite, finite, finite),
    contact=st.booleans(),
)
def test_sensor_readings_round_trip_for_any_valid_content(step, ranges, pose, contact):
    m = SensorReading(step=step, run=RUN, t_s=0.0, ranges_m=ranges, pose=pose, contact=contact)
    back = SensorReading.decode(m.encode())
    assert back == m
    assert back.ranges_m.dtype == np.float32 and back.pose.dtype == np.float64


@example(raw=b"\xde\x00\x01\xa5\x00\x00\x00\x00\x80")  # a map key of bad UTF-8 (found so)
@given(st.binary(max_size=200))
def test_arbitrary_bytes_never_crash_a_decoder(raw):
    for kind in (MotorCommand, SensorReading, Stimulation, SpikeBatch, Description):
        try:
            kind.decode(raw)
        except ProtocolError:
            pass


@given(
    st.dictionaries(
        st.sampled_from(["v", "step", "left_mps", "right_mps", "x"]),
        st.one_of(st.integers(-(2**63), 2**64 - 1), st.floats(), st.text(max_size=3), st.none()),
    )
)
def test_arbitrary_maps_are_motor_commands_or_protocol_errors(data):
    raw = msgpack.packb(data)
    try:
        m = MotorCommand.decode(raw)
    except ProtocolError:
        return
    assert math.isfinite(m.left_mps) and math.isfinite(m.right_mps) and m.step >= 0


def _value_for(spec):
    """Values for one schema field, mostly of the right kind but not always valid (NaN,
    infinity, out of range, other types and dtypes, unequal lengths in a group)."""
    if isinstance(spec, Array):
        sizes = st.sampled_from([0, 1, 2, 3, SMALL_ARRAY + 6])
        size = st.shared(sizes, key=spec.group) if spec.group else sizes
        size = st.one_of(size, size, sizes)
        dtype = st.sampled_from([spec.native] * 3 + [np.dtype(np.float64), np.dtype(np.int64)])

        def array(dt):
            elements = st.floats(width=32) if dt.kind == "f" else st.integers(0, 2**31)
            return size.flatmap(lambda n: st.lists(elements, min_size=n, max_size=n)).map(
                lambda values: np.array(values, dtype=dt)
            )

        return dtype.flatmap(array)
    right = {
        float: st.floats(),
        int: st.integers(-3, 2**40),
        bool: st.booleans(),
        str: st.text(max_size=40),
    }[spec.kind]
    return st.one_of(right, right, right, st.integers(-3, 3), st.none(), st.just("a"))


@given(st.data())
def test_the_quick_validation_path_accepts_only_what_the_full_one_leaves_unchanged(data):
    for kind in (MotorCommand, SensorReading, Stimulation, SpikeBatch):
        values = {
            name: data.draw(_value_for(spec), label=name) for name, spec in kind.SCHEMA.items()
        }
        message = object.__new__(kind)
        message.__dict__.update(values)
        if message._accepted_at_once():
            message._validate_fields()  # must not raise
            for name, value in values.items():
                assert getattr(message, name) is value


@pytest.mark.parametrize("example", EXAMPLES[:6], ids=lambda m: type(m).__name__)
def test_valid_loop_messages_take_the_quick_validation_path(example):
    assert example._accepted_at_once()


# --------------------------------------------------------------------------- decoding fast path

LOOP_TYPES = (MotorCommand, SensorReading, Stimulation, SpikeBatch)
MESSAGE_TYPES = {type(m) for m in EXAMPLES}


@pytest.mark.parametrize("message", [m for m in EXAMPLES if type(m) in LOOP_TYPES], ids=str)
def test_valid_loop_messages_decode_typed_and_encode_as_msgpack_would(message, monkeypatch):
    """A loop message's bytes are decoded by msgspec into its fields, checked, without the
    general path; and its encoding is byte for byte what msgpack makes of its map."""

    def general_path(data):
        raise AssertionError("a valid loop message took the general path")

    raw = message.encode()
    assert raw == msgpack.packb(message.to_dict(), use_bin_type=True)
    monkeypatch.setattr(type(message), "from_dict", general_path)
    assert type(message).decode(raw) == message


@pytest.mark.parametrize("kind", sorted(MESSAGE_TYPES, key=lambda k: k.__name__), ids=str)
def test_every_dataclass_field_is_in_the_schema(kind):
    # from_dict fills a bare instance with the SCHEMA fields only
    assert [f.name for f in dataclasses.fields(kind)] == list(kind.SCHEMA)


@pytest.mark.parametrize("message", EXAMPLES, ids=lambda m: type(m).__name__)
def test_valid_messages_decode_on_the_fast_path_and_re_encode_to_the_same_bytes(
    message, monkeypatch
):
    def full_path(data):
        raise AssertionError("a valid message took the full path")

    monkeypatch.setattr(type(message), "_from_dict_in_full", full_path)
    raw = message.encode()
    back = type(message).decode(raw)
    assert back == message
    assert back.encode() == raw
    for name, spec in back.SCHEMA.items():
        value = getattr(back, name)
        if isinstance(spec, Array) and value is not None:
            assert value.dtype == spec.native and not value.flags.writeable


def _spikes(**fields):
    base = {
        "v": SCHEMA_VERSION,
        "step": 3,
        "run": RUN,
        "t0_s": 0.03,
        "t1_s": 0.04,
        "channel": np.array([4, 1, 9], "<u4").tobytes(),
        "t_ms": np.array([0.5, 2.0, 9.5], "<f4").tobytes(),
    }
    base.update(fields)
    return msgpack.packb({k: v for k, v in base.items() if v is not ...}, use_bin_type=True)


def _pulses(**fields):
    base = {
        "v": SCHEMA_VERSION,
        "step": 3,
        "run": RUN,
        "t0_s": 0.03,
        "t1_s": 0.04,
        "channel": np.array([4, 1], "<u4").tobytes(),
        "amplitude_ua": np.array([10, 20], "<f4").tobytes(),
        "width_ms": np.array([0.2, 0.2], "<f4").tobytes(),
        "onset_ms": np.array([0.0, 5.0], "<f4").tobytes(),
    }
    base.update(fields)
    return msgpack.packb({k: v for k, v in base.items() if v is not ...}, use_bin_type=True)


def _f4(*values):
    return np.array(values, "<f4").tobytes()


LONG = SMALL_ARRAY + 6  # past the plain-Python size: compiled checks (hub/array_kernels.py)


@pytest.mark.parametrize(
    "kind, raw, error",
    [
        (SpikeBatch, _spikes(), None),
        (SpikeBatch, _spikes(step=...), "missing"),
        (SpikeBatch, _spikes(step=None), "missing"),
        (SpikeBatch, _spikes(t_ms=...), "missing"),  # defaults are the constructor's only
        (SpikeBatch, _spikes(step=-1), "range"),
        (SpikeBatch, _spikes(step=1.0), "type"),
        (SpikeBatch, _spikes(t0_s=float("inf"), t1_s=float("inf")), "non_finite"),
        (SpikeBatch, _spikes(t0_s=-0.01), "range"),
        (SpikeBatch, _spikes(t0_s=0), None),  # an int where a float is due: converted
        (SpikeBatch, _spikes(t1_s=0.02), "inconsistent"),  # precedes t0_s
        (SpikeBatch, _spikes(t_ms=_f4(0.5, float("nan"), 9.5)), "non_finite"),
        (SpikeBatch, _spikes(t_ms=_f4(0.5, float("inf"), 9.5)), "non_finite"),
        (SpikeBatch, _spikes(t_ms=_f4(-0.5, 2.0, 9.5)), "range"),
        (SpikeBatch, _spikes(t_ms=_f4(0.5, 9.5, 2.0)), "inconsistent"),  # unsorted
        (SpikeBatch, _spikes(t_ms=_f4(0.5, 2.0, 10.5)), "range"),  # beyond the window
        (SpikeBatch, _spikes(t_ms=_f4(0.5, 2.0)), "inconsistent"),  # group length
        (SpikeBatch, _spikes(t_ms=_f4(0.5, 2.0, 9.5)[:-1]), "array"),  # not whole float32
        (SpikeBatch, _spikes(t_ms=np.array([0.5, 2.0, 9.5]).tobytes()), "inconsistent"),
        (SpikeBatch, _spikes(t_ms=[0.5, 2.0, 9.5]), "type"),
        (SpikeBatch, _spikes(channel="abc"), "type"),
        (SpikeBatch, _spikes(channel=None), "type"),  # as ever: nil is not bin
        (
            SpikeBatch,
            _spikes(
                channel=np.zeros(LONG, "<u4").tobytes(),
                t_ms=np.r_[np.linspace(0, 9, LONG - 1), np.nan].astype("<f4").tobytes(),
            ),
            "non_finite",
        ),
        (
            SpikeBatch,
            _spikes(
                channel=np.zeros(LONG, "<u4").tobytes(),
                t_ms=np.linspace(9, 0, LONG).astype("<f4").tobytes(),
            ),
            "inconsistent",
        ),
        (Stimulation, _pulses(), None),
        (Stimulation, _pulses(onset_ms=_f4(0.0, -1.0)), "range"),
        (Stimulation, _pulses(width_ms=_f4(0.2, float("nan"))), "non_finite"),
        (Stimulation, _pulses(amplitude_ua=_f4(10, float("-inf"))), "non_finite"),
        (Stimulation, _pulses(amplitude_ua=_f4(-10, 20)), None),  # no bound on amplitude
        (Stimulation, _pulses(amplitude_ua=_f4(10)), "inconsistent"),
        (Stimulation, _pulses(onset_ms=_f4(0.0)), "inconsistent"),
        (Stimulation, _pulses(channel=...), "missing"),
        (Stimulation, _pulses(channel=b"", amplitude_ua=b"", width_ms=b"", onset_ms=b""), None),
        (Stimulation, _pulses(channel=b"\x01\x00\x00"), "array"),
        (Stimulation, _pulses(extra=1), "unknown"),
        (Stimulation, _pulses(v=1), "version"),
        (
            MotorCommand,
            msgpack.packb({"v": SCHEMA_VERSION, "step": 0, **MOTOR_WINDOW, "left_mps": 0.0}),
            "missing",
        ),
        (
            MotorCommand,
            msgpack.packb(
                {"v": SCHEMA_VERSION, "step": 0, **MOTOR_WINDOW, "left_mps": 0, "right_mps": 1}
            ),
            None,
        ),
        (
            MotorCommand,
            msgpack.packb(
                {
                    "v": SCHEMA_VERSION,
                    "step": 0,
                    **MOTOR_WINDOW,
                    "left_mps": 0.0,
                    "right_mps": 1e400,
                }
            ),
            "non_finite",
        ),
        (
            MotorCommand,
            msgpack.packb(
                {
                    "v": SCHEMA_VERSION,
                    "step": 0,
                    **MOTOR_WINDOW,
                    "left_mps": 0.0,
                    "right_mps": 0.0,
                    "v_mps": None,
                }
            ),
            None,
        ),
        (
            MotorCommand,
            msgpack.packb(
                {
                    "v": SCHEMA_VERSION,
                    "step": 0,
                    **MOTOR_WINDOW,
                    "left_mps": 0.0,
                    "right_mps": 0.0,
                    "omega_rad_s": True,
                }
            ),
            "type",
        ),
    ],
    ids=lambda v: v.__name__ if isinstance(v, type) else (v if isinstance(v, str) else ""),
)
def test_the_fast_and_full_decoding_paths_agree(kind, raw, error):
    """Each case is decoded both ways: the same message, or the same ProtocolError."""
    data = msgpack.unpackb(raw)
    fast, full = _outcome(kind.from_dict, data), _outcome(kind._from_dict_in_full, data)
    if error is None:
        assert isinstance(fast, kind) and fast == full
        assert kind.decode(raw) == fast
    elif error in ("version", "unknown"):  # checked before the paths part
        assert fast[0] == error
    else:
        assert fast == full and fast[0] == error
        with pytest.raises(ProtocolError) as err:
            kind.decode(raw)
        assert err.value.kind == error


def _wire_value_for(spec):
    """A field's value as it may arrive: arrays as bytes of any dtype (so of any length,
    with any bits), otherwise as :func:`_value_for` draws it."""
    if isinstance(spec, Array):
        as_bytes = _value_for(spec).map(np.ndarray.tobytes)
        return st.one_of(as_bytes, as_bytes, as_bytes, st.none(), st.just([1.0]))
    return _value_for(spec)


@given(st.data())
def test_the_fast_decoding_path_agrees_with_the_full_one_on_any_map(data):
    for kind in LOOP_TYPES:
        fields = {
            name: data.draw(_wire_value_for(spec), label=name) for name, spec in kind.SCHEMA.items()
        }
        if kind is SpikeBatch and type(fields["t_ms"]) is bytes:  # often sorted and in window
            fields["t1_s"] = 1e9
            if data.draw(st.booleans(), label="sorted"):
                n = len(fields["t_ms"]) // 4
                fields["t_ms"] = np.sort(np.frombuffer(fields["t_ms"][: 4 * n], "<f4")).tobytes()
        some = st.sets(st.sampled_from(list(fields)), max_size=2)
        absent = data.draw(st.one_of(st.just(set()), st.just(set()), some), label="absent")
        wire = {"v": SCHEMA_VERSION} | {k: v for k, v in fields.items() if k not in absent}

        fast, full = _outcome(kind.from_dict, wire), _outcome(kind._from_dict_in_full, wire)
        assert fast == full
        # and decoding the bytes (msgspec first, the general path for what it refuses)
        assert _outcome(kind.decode, msgpack.packb(wire, use_bin_type=True)) == full


def _outcome(from_dict, data):
    """The message, or the kind and text of the ProtocolError."""
    try:
        return from_dict(data)
    except ProtocolError as exc:
        return exc.kind, str(exc)


def test_default_arrays_are_shared_read_only_and_decoded_ones_read_only_from_any_buffer():
    a, b = Stimulation.none(W(1)), Stimulation.none(W(2))
    assert a.channel is b.channel and not a.channel.flags.writeable
    assert a.channel.dtype == np.uint32 and a.onset_ms.dtype == np.float32
    raw = EXAMPLES[5].encode()
    for buffer in (bytearray(raw), memoryview(raw)):
        m = SpikeBatch.decode(buffer)
        assert m == EXAMPLES[5] and not m.t_ms.flags.writeable
    fresh = np.array([0.1, 0.2], np.float32)
    SensorReading(step=1, run=RUN, t_s=0.0, ranges_m=fresh, pose=[0, 0, 0], contact=False)
    assert not fresh.flags.writeable


def test_encoding_from_many_threads_at_once_gives_each_its_own_bytes():
    expected = [m.encode() for m in EXAMPLES]
    failures = []

    def encode_all():
        for _ in range(200):
            if [m.encode() for m in EXAMPLES] != expected:
                failures.append(1)

    threads = [threading.Thread(target=encode_all) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not failures


def test_a_message_that_fails_to_encode_leaves_the_next_one_whole():
    bad = ControlReply(ok=True, state="x", data={"x": object()})
    with pytest.raises(TypeError):
        bad.encode()
    assert ControlRequest.decode(ControlRequest(cmd="stop").encode()) == ControlRequest(cmd="stop")


# --------------------------------------------------------------------------- contract v2


@pytest.mark.parametrize("version", [True, 3.0, 4.0, 1, 2, 5, "4"])
def test_the_version_must_be_exactly_the_integer_3_or_4(version):
    data = MotorCommand.stop(W(1)).to_dict()
    data["v"] = version
    with pytest.raises(ProtocolError) as err:
        MotorCommand.from_dict(data)
    assert err.value.kind == "version"


def test_a_version_3_message_reads_as_version_4():
    """v4 only added a field: runs recorded under v3 stay readable."""
    data = MotorCommand.stop(W(1)).to_dict()
    assert data["v"] == SCHEMA_VERSION == 4
    data["v"] = 3
    assert MotorCommand.from_dict(data) == MotorCommand.stop(W(1))


# --------------------------------------------------------------------------- contract v4


def test_a_part_of_a_steps_spikes_says_so_and_carries_no_late_spikes():
    part = SpikeBatch(**W(2).stamp, channel=[3], t_ms=[1.0], partial=True)
    assert SpikeBatch.decode(part.encode()).partial is True
    assert "partial" not in SpikeBatch(**W(2).stamp).to_dict()  # a whole batch: absent
    for bad in ({"partial": False}, {"partial": True, "late_channel": [1], "late_t_ms": [-1.0]}):
        with pytest.raises(ProtocolError) as err:
            SpikeBatch(**W(2).stamp, **bad)
        assert err.value.kind == "inconsistent"


def test_a_steps_spikes_are_its_parts_and_its_batch_in_time_order():
    first = SpikeBatch(**W(2).stamp, channel=[3, 4], t_ms=[1.0, 6.0], partial=True)
    second = SpikeBatch(**W(2).stamp, channel=[5], t_ms=[2.0], partial=True)
    batch = SpikeBatch(**W(2).stamp, channel=[6], t_ms=[9.0], late_channel=[7], late_t_ms=[-2.0])
    merged = merge_parts([first, second], batch)
    assert merged.channel.tolist() == [3, 5, 4, 6]
    assert merged.t_ms.tolist() == [1.0, 2.0, 6.0, 9.0]
    assert merged.partial is None and merged.late_channel.tolist() == [7]
    assert merge_parts([], batch) is batch


def test_a_step_window_is_the_steps_run_time():
    w = StepWindow.of(RUN, 7, 0.01)
    assert (w.step, w.t0_s, w.t1_s) == (7, 7 * 0.01, 8 * 0.01)
    assert w.period_s == pytest.approx(0.01)
    assert MotorCommand.stop(w).window == w and Stimulation.none(w).window == w


def test_a_pulse_must_start_inside_its_step():
    w = W(3)
    Stimulation(**w.stamp, channel=[1], amplitude_ua=[1], width_ms=[1], onset_ms=[9.9])
    with pytest.raises(ProtocolError, match="outside the step"):
        Stimulation(**w.stamp, channel=[1], amplitude_ua=[1], width_ms=[1], onset_ms=[10.0])


def test_a_window_must_have_a_length():
    with pytest.raises(ProtocolError, match="must follow"):
        MotorCommand(step=1, run=RUN, t0_s=0.02, t1_s=0.02, left_mps=0.0, right_mps=0.0)


def _run_start(**fields) -> RunStart:
    values = dict(
        run="ab" * 16,
        period_ms=10.0,
        n_steps=100,
        mode="lockstep",
        start_unix_s=1.0,
        deadline_ms=10.0,
        key=bytes(16),
    )
    return RunStart(**{**values, **fields})


def test_the_run_announcement_round_trips_and_is_told_from_its_end():
    start = _run_start(seed=3)
    assert decode_run_request(start.encode()) == start
    assert start.window(2) == StepWindow.of(start.run, 2, 0.01)
    end = RunEnd(run=start.run, outcome="completed")
    assert decode_run_request(end.encode()) == end


@pytest.mark.parametrize(
    "fields, kind",
    [
        ({"run": "AB" * 16}, "range"),  # upper case
        ({"run": "ab"}, "range"),  # too short
        ({"mode": "fast"}, "range"),
        ({"key": bytes(8)}, "type"),
        ({"period_ms": 0.0}, "range"),
        ({"n_steps": 0}, "range"),
    ],
)
def test_a_bad_run_announcement_is_refused_with_its_kind(fields, kind):
    with pytest.raises(ProtocolError) as err:
        _run_start(**fields)
    assert err.value.kind == kind


def test_a_run_request_is_told_apart_by_its_fields():
    assert isinstance(decode_run_request(RunHold(run=RUN, hold=False).encode()), RunHold)
    assert isinstance(decode_run_request(RunEnd(run=RUN, outcome="completed").encode()), RunEnd)
