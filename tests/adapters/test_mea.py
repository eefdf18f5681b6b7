"""The MEA adapter against its emulator over real TCP on loopback: the RHX protocol, spikes,
stimulation that evokes a response, the instrument's clock, and safety."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from collections import Counter

import numpy as np
import pytest

from adapters.mea.driver import ClockMap
from adapters.mea.emulator import DEFAULT_CULTURE, IntanEmulator
from adapters.mea.endpoint import MeaEndpoint
from adapters.mea.layout import ElectrodeLayout
from adapters.mea.rhx import RhxDriver, RhxError, spike_record, spike_record_bytes, spike_records
from adapters.mea.safety import BiphasicPulse, PulseLimits, SafetyGate
from hub import conformance
from hub.config import ConfigError, load_config
from sim_network import Network
from sim_network.config import load_config as load_culture
from tests.harness import needs_fifo, wait_for

HYBRID = "configs/hybrid_mea.toml"


@pytest.fixture
def emulator():
    with IntanEmulator(seed=1) as emu:
        yield emu


def driver_for(emu: IntanEmulator) -> RhxDriver:
    return RhxDriver(emu.layout, command_port=emu.command_port, spike_port=emu.spike_port)


# ---------------------------------------------------------------- protocol, layout


def test_spike_records_split_across_reads_are_joined_and_bad_bytes_skipped():
    counts = Counter()
    data = spike_record("a-010", 1234) + b"\x01\x02junk" + spike_record("b-003", 99)
    buffer = bytearray(data[:9])  # a record cut in the middle
    assert spike_records(buffer, counts).size == 0
    buffer += data[9:]
    records = spike_records(buffer, counts)
    assert records["name"].tolist() == [b"a-010", b"b-003"]
    assert records["timestamp"].tolist() == [1234, 99]
    assert counts["bad_magic"] >= 1 and not buffer


def test_records_of_a_burst_are_read_as_one_array_and_match_one_by_one():
    names = np.array([b"a-%03d" % (i % 30) for i in range(3000)], "S5")
    timestamps = np.arange(3000, dtype=np.uint32) * 7
    data = spike_record_bytes(names, timestamps)
    assert data[:14] == spike_record("a-000", 0)  # the same bytes as one record alone
    buffer = bytearray(data + data[:5])
    records = spike_records(buffer, Counter())
    assert records["name"].tolist() == names.tolist()
    assert records["timestamp"].tolist() == timestamps.tolist()
    assert len(buffer) == 5  # the cut record waits for its rest


def test_the_clock_map_follows_each_new_pair_and_is_not_refitted_without_one():
    clock = ClockMap([(t, 100.0 + t * (1 + 20e-6)) for t in np.linspace(0.0, 10.0, 50)])
    a, b = clock.fit()
    assert a == pytest.approx(100.0) and (b - 1.0) * 1e6 == pytest.approx(20.0)
    assert clock.fit() is clock.fit()  # the same fit, not fitted again
    clock.pairs.append((11.0, 100.0 + 11.0 * (1 + 20e-6) + 1e-3))  # a pair 1 ms off the line
    assert clock.fit()[0] != a  # refitted
    before = clock.fit()
    del clock.pairs[0]  # as the driver keeps the last 200: same length, a new last pair
    clock.pairs.append((12.0, 100.0 + 12.0 * (1 + 20e-6) + 2e-3))
    assert clock.fit() != before


def test_the_default_layout_is_the_mcs_60_grid_on_two_ports():
    layout = ElectrodeLayout.mcs60()
    assert layout.n == 60 and layout.names[0] == "a-000" and layout.names[59] == "b-027"
    assert np.ptp(layout.x_um) == 7 * 200.0 and np.ptp(layout.y_um) == 7 * 200.0


def test_a_labs_layout_file_and_a_bad_one(tmp_path):
    good = tmp_path / "l.csv"
    good.write_text("name,x_um,y_um\nc-000,0,0\nc-001,100,0\n")
    assert ElectrodeLayout.from_file(good).names == ("c-000", "c-001")
    # written as RHX shows them: the driver matches the instrument's names in lower case
    upper = tmp_path / "upper.csv"
    upper.write_text("name,x_um,y_um\nA-010,0,0\nA-011,100,0\n")
    assert ElectrodeLayout.from_file(upper).index() == {"a-010": 0, "a-011": 1}
    bad = tmp_path / "bad.csv"
    bad.write_text("name,x_um,y_um\nc-000,0,0\nC-000,1,1\n")  # one electrode twice
    with pytest.raises(ConfigError, match="culture.params.layout_file.*unique"):
        ElectrodeLayout.from_file(bad)


# ---------------------------------------------------------------- the driver


def test_every_write_is_confirmed_and_pulse_parameters_read_back(emulator):
    d = driver_for(emulator)
    d.open()
    try:
        assert d.sample_rate_hz == 30_000
        d.deliver([BiphasicPulse(5, 40.0, 150.0, True)])
        name = emulator.layout.names[5]
        assert d.get(f"{name}.firstphaseamplitudemicroamps") == "40"
        assert d.get(f"{name}.secondphasedurationmicroseconds") == "150"
        assert d.get(f"{name}.polarity") == "NegativeFirst"
        assert d.get(f"{name}.stimenabled") == "true"
        with pytest.raises(RhxError, match="Error"):
            d.get("nosuchparameter")
    finally:
        d.close()


def test_each_trigger_fires_exactly_its_electrodes_and_only_changes_are_written(emulator):
    d = driver_for(emulator)
    d.open()
    try:
        d.start()
        d.deliver([BiphasicPulse(1, 10.0, 200.0, True), BiphasicPulse(2, 10.0, 200.0, True)])
        wait_for(lambda: len(emulator.triggers) == 1, 2.0)
        commands = emulator.commands
        d.deliver([BiphasicPulse(2, 30.0, 200.0, True), BiphasicPulse(3, 10.0, 200.0, True)])
        wait_for(lambda: len(emulator.triggers) == 2, 2.0)
        assert [sorted(fired) for _, fired in emulator.triggers] == [[1, 2], [2, 3]]
        # 1 disabled; 2's two amplitudes; 3's six parameters: 9 sets and their 9 gets, 3
        # uploads and the trigger
        assert emulator.commands - commands == 9 + 9 + 3 + 1
        assert emulator.uploaded[emulator.layout.names[2]]["firstphaseamplitudemicroamps"] == "30"
        d.stop()
        assert not d.enabled
        wait_for(lambda: all(p["stimenabled"] == "false" for p in emulator.uploaded.values()), 2.0)
    finally:
        d.close()


def test_the_emulators_culture_is_compiled_when_built_and_starts_as_built(emulator):
    # Compiled at the run's first chunk instead, the culture fell seconds behind real time
    # and a first hybrid run had every tenth step late (each pulse's command waited).
    code = (
        "from adapters.mea.emulator import IntanEmulator; from sim_network import kernels, "
        "pulse_kernels; IntanEmulator(seed=1).stop(); "
        "print(len(kernels.advance.signatures), len(pulse_kernels.scheduled.signatures))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert [int(n) > 0 for n in done.stdout.split()] == [True, True]
    fresh = Network(load_culture(DEFAULT_CULTURE, ['channels="mea"']), seed=1)
    a, b = emulator.net.run(200.0), fresh.run(200.0)
    assert a.channel.size > 0
    assert np.array_equal(a.channel, b.channel) and np.array_equal(a.t_ms, b.t_ms)


@needs_fifo
def test_the_emulator_may_run_its_threads_at_a_real_time_priority():
    """So that a realtime run's raised threads do not starve it (an instrument has a
    machine of its own)."""
    with IntanEmulator(realtime_priority=3) as emu:
        d = driver_for(emu)
        d.open()
        try:
            mine = {t.name: t.native_id for t in threading.enumerate()}
            served = [tid for name, tid in mine.items() if name.startswith("intan-")]
            assert len(served) == 3 and os.sched_getscheduler(0) == os.SCHED_OTHER
            try:
                policies = {os.sched_getscheduler(tid) & ~os.SCHED_RESET_ON_FORK
                            for tid in served}  # fmt: skip
            except ProcessLookupError:
                pytest.fail("an emulator thread ended")
            assert policies == {os.SCHED_FIFO}
        finally:
            d.close()


def test_a_write_the_instrument_did_not_take_stops_the_trigger(emulator, monkeypatch):
    answer = emulator._command

    def ignoring_polarity(line: str) -> str:  # the instrument drops one write of the batch
        return "" if line.lower().startswith("set") and "polarity" in line.lower() else answer(line)

    monkeypatch.setattr(emulator, "_command", ignoring_polarity)
    d = driver_for(emulator)
    d.open()
    try:
        with pytest.raises(RhxError, match="polarity"):
            d.deliver([BiphasicPulse(5, 40.0, 150.0, True), BiphasicPulse(6, 40.0, 150.0, True)])
        assert emulator.triggers == [] and emulator.uploaded == {}
    finally:
        d.close()


def test_spikes_come_by_channel_and_the_clock_offset_is_within_a_sample(emulator):
    d = driver_for(emulator)
    d.open()
    try:
        d.start()
        time.sleep(1.0)  # a second of the culture's activity to look at
        channel, inst_s, arrived = d.take_spikes()
        assert channel.size > 100 and channel.max() < 60
        # the emulator's clock: samples since run mode began at its _run_t0 (monotonic)
        offset_s, drift = d.clock.fit()
        assert abs(-emulator._run_t0 - offset_s) < 1 / 30_000 + 2e-4  # a sample + loopback jitter
        local = d.clock.to_local(inst_s)
        assert np.all(local <= arrived + 1e-3)  # a spike is seen after it happened
    finally:
        d.close()


@pytest.mark.slow  # seconds of the emulated culture
def test_stimulation_evokes_a_response_peaking_10_to_100_ms_later(emulator):
    d = driver_for(emulator)
    d.open()
    try:
        d.start()
        time.sleep(0.5)
        sites = [20, 21, 28, 29]  # four electrodes near the centre
        fired_at = []
        for _ in range(15):
            fired_at.append(time.monotonic())
            d.deliver([BiphasicPulse(c, 100.0, 400.0, True) for c in sites])
            time.sleep(0.4)  # the stimulation protocol: one train every 400 ms
        channel, inst_s, _ = d.take_spikes()
        t = d.clock.to_local(inst_s)
        lags_ms = np.concatenate([(t - f) * 1e3 for f in fired_at])
        lags_ms = lags_ms[(lags_ms >= 0) & (lags_ms < 300)]
        counts, edges = np.histogram(lags_ms, bins=np.arange(0, 305, 5))
        peak_ms = edges[np.argmax(counts)]
        assert 10 <= peak_ms <= 100, (peak_ms, counts[:25])
    finally:
        d.close()


# ---------------------------------------------------------------- safety


@pytest.mark.parametrize(
    "amplitude_ua, width_ms, reason",
    [
        (150.0, 0.4, "amplitude"),  # over 100 µA
        (100.0, 1.0, "phase"),  # a 500 µs phase
        (0.0, 0.01, "phase"),  # a 5 µs phase: too short to be charge balanced
    ],
)
def test_an_unsafe_pulse_is_refused_and_counted_never_clipped(amplitude_ua, width_ms, reason):
    gate = SafetyGate(PulseLimits())
    assert gate.admit(3, amplitude_ua, width_ms, 0.0).startswith(reason)
    assert gate.refused == {reason: 1} and gate.admitted == 0


def test_a_pulse_exactly_at_a_limit_is_admitted_though_it_came_as_float32():
    """Widths and amplitudes travel as float32: 0.8 ms arrives as 0.80000001 ms, a phase of
    400.000006 µs. A pulse asked for exactly at the limits was refused ("phase 400 µs >
    max_phase_us 400"); the next float32 value above a limit still is."""
    limits = PulseLimits(electrode_diameter_um=1000.0)  # a charge limit out of the way
    gate = SafetyGate(limits)
    f32 = lambda x: float(np.float32(x))  # noqa: E731
    longest, shortest = 2 * limits.max_phase_us / 1e3, 2 * limits.min_phase_us / 1e3
    assert not isinstance(gate.admit(0, f32(limits.max_amplitude_ua), f32(longest), 0.0), str)
    assert not isinstance(gate.admit(1, 10.0, f32(shortest), 0.0), str)
    above = float(np.nextafter(np.float32(longest), np.float32(1.0)))
    assert gate.admit(2, 10.0, above, 0.0).startswith("phase")


def test_charge_is_checked_against_the_electrodes_size():
    limits = PulseLimits(electrode_diameter_um=10.0, max_phase_us=1000.0)
    assert limits.max_charge_nc == pytest.approx(18.06, abs=0.01)  # devices.md: ~18 nC
    assert SafetyGate(limits).admit(0, 100.0, 0.4, 0.0).startswith("charge")


def test_too_frequent_pulses_are_refused_per_electrode_and_in_total():
    gate = SafetyGate(PulseLimits(max_pulse_hz=2, max_total_hz=3))
    assert not isinstance(gate.admit(0, 50, 0.4, 0.0), str)
    assert not isinstance(gate.admit(0, 50, 0.4, 0.1), str)
    assert gate.admit(0, 50, 0.4, 0.2).startswith("rate")  # a third within a second
    assert not isinstance(gate.admit(1, 50, 0.4, 0.3), str)
    assert gate.admit(2, 50, 0.4, 0.4).startswith("total_rate")
    assert not isinstance(gate.admit(0, 50, 0.4, 1.05), str)  # a second later: allowed


@pytest.mark.parametrize(
    "override, named",
    [
        ('culture.params.safety.shape="monophasic"', "safety.shape must be 'biphasic'"),
        ('culture.params.safety.mode="voltage"', "safety.mode must be 'current'"),
        ('culture.params.safety.polarity="sideways"', "safety.polarity"),
        ("culture.params.safety.max_amplitude_ua=-1", "max_amplitude_ua"),
        ('culture.params.driver="nidaq"', r"culture.params.driver must be one of \['lsl', 'rhx'\]"),
        # the RHX keys of hybrid_mea.toml are not the LSL driver's
        (
            'culture.params.driver="lsl"',
            r"unknown key\(s\) \['command_port', 'host', 'spike_port'\]",
        ),
        ('loop.mode="lockstep"', "loop.mode: a culture on an MEA is a real device"),
        # its replies trail its windows: found from the file, not once the endpoints start
        ("loop.deadline_ms=0", r"loop.deadline_ms must lie between one and two periods"),
        ("loop.deadline_ms=25", r"loop.deadline_ms must lie between one and two periods"),
        ("culture.params.freeze_s=-1", "culture.params.freeze_s"),
        # a command waits up to 1 s for its reply, between two beats: shorter, an
        # instrument only slow to answer would be disabled
        ("culture.params.freeze_s=0.5", r"culture.params.freeze_s 0.5 s is under 1.2 s"),
    ],
)
def test_unsafe_or_unsupported_settings_are_named_before_anything_opens(override, named):
    cfg = load_config(HYBRID, [override])
    with pytest.raises(ConfigError, match=named):
        MeaEndpoint.check_config(cfg.culture, cfg)


# ---------------------------------------------------------------- the endpoint


@pytest.fixture
def emulators():
    started: list[IntanEmulator] = []

    def new() -> IntanEmulator:
        started.append(IntanEmulator(seed=1).start())
        return started[-1]

    yield new
    for emu in started:
        emu.stop()


def endpoint_for(emu: IntanEmulator, **limits) -> MeaEndpoint:
    return MeaEndpoint(driver_for(emu), PulseLimits(**limits), reply_margin_ms=1.0)


@pytest.mark.parametrize("check", conformance.CHECKS, ids=lambda c: c.__name__)
def test_the_mea_endpoint_keeps_the_contract(check, emulators):
    check(lambda: endpoint_for(emulators(), max_pulse_hz=1000, max_total_hz=10_000))


def test_refused_pulses_never_reach_the_instrument(emulators):
    from hub.protocol import Stimulation

    emu = emulators()
    # 10 µm electrodes: 18 nC per phase at most
    with conformance.served(lambda: endpoint_for(emu, electrode_diameter_um=10.0)) as hub:
        assert hub.start(mode="realtime").ok
        # over the described amplitude limit: the whole message dropped by the endpoint
        over = Stimulation(**hub.window(0).stamp, channel=[1], amplitude_ua=[500.0],
                           width_ms=[0.4], onset_ms=[0.0])  # fmt: skip
        hub.send(over)
        # within the described limits, over the electrode's safe charge: that pulse refused
        w = hub.window(1)
        charge = Stimulation(**w.stamp, channel=[2], amplitude_ua=[100.0], width_ms=[0.4],
                             onset_ms=[0.0])  # fmt: skip
        hub.send(charge)
        assert hub.reply().step == 1
        counters = hub.counters()
        assert counters["dropped"] == {"limit": 1}
        assert counters["device"]["pulses_refused"] == {"charge": 1}
        assert counters["device"]["pulses_admitted"] == 0
        assert emu.triggers == []  # nothing fired


def test_when_the_hub_vanishes_no_trigger_follows(emulators):
    emu = emulators()
    with conformance.served(lambda: endpoint_for(emu)) as hub:
        assert hub.start(mode="realtime").ok
        from hub.protocol import Stimulation

        w = hub.window(0)
        later = Stimulation(**w.stamp, channel=[3], amplitude_ua=[50.0], width_ms=[0.4],
                            onset_ms=[9.0])  # fmt: skip
        hub.send(later)
        hub.vanish()
        wait_for(lambda: hub.hooks.calls["end_run"] >= 1, 10.0)
        ended = time.monotonic()
        n = len(emu.triggers)
        time.sleep(0.3)  # any pending pulse would fire in this time
        assert all(t <= ended for t, _ in emu.triggers[n:]) and len(emu.triggers) == n
        assert emu.values["runmode"] == "stop"


def test_a_pause_or_an_input_timeout_stops_stimulation_but_not_the_recording(emulators):
    """Making the culture safe disables the electrodes; the instrument stays in its run,
    so the spikes and its clock go on for the steps after a pause. Run mode goes off only
    when the run ends. (A CI run of configs/hybrid_both.toml had its input timeout fire just
    after the run began: with run mode turned off then, every later spike came late.)"""
    emu = emulators()
    with conformance.served(lambda: endpoint_for(emu)) as hub:
        assert hub.start(mode="realtime").ok
        run_t0 = emu._run_t0
        assert emu.values["runmode"] == "run" and run_t0 is not None
        assert hub.hold(True).ok  # made safe at once
        wait_for(lambda: hub.hooks.calls["make_safe"] >= 1, 5.0)
        time.sleep(0.6)  # past the suite's input timeout too: made safe again
        assert emu.values["runmode"] == "run" and emu._run_t0 == run_t0
        assert not hub.endpoint.driver.enabled
        clock_pairs = len(hub.endpoint.driver.clock.pairs)
        wait_for(lambda: len(hub.endpoint.driver.clock.pairs) > clock_pairs, 5.0)
        _, drift = hub.endpoint.driver.clock.fit()
        assert abs(drift - 1.0) < 0.01  # the instrument's clock still runs
        assert hub.hold(False).ok
        assert hub.end().ok
        wait_for(lambda: hub.hooks.calls["end_run"] >= 1, 5.0)
        assert emu.values["runmode"] == "stop"


@pytest.mark.parametrize("stream_spikes_ms", [1.0, 0.0])
def test_a_windows_spikes_go_out_as_they_come_in_parts_then_the_rest(emulators, stream_spikes_ms):
    """Contract v4: while a window lasts, its spikes go to the hub in parts (each before
    the window's batch, which holds the rest); with ``stream_spikes_ms = 0``, all in the
    batch after the window."""
    from hub.protocol import SpikeBatch, merge_parts

    emu, period_s = emulators(), 0.5  # the emulated culture fires >100 spikes/s

    def make() -> MeaEndpoint:
        return MeaEndpoint(driver_for(emu), PulseLimits(), reply_margin_ms=1.0,
                           stream_spikes_ms=stream_spikes_ms)  # fmt: skip

    with conformance.served(make) as hub:
        assert hub.start(mode="realtime", period_ms=period_s * 1e3).ok
        hub.send(hub.valid_input(0))
        sent = time.monotonic()
        came: list[tuple[float, SpikeBatch]] = []  # (arrival, output) up to the batch
        while not came or came[-1][1].partial:
            payload, attachment = hub.outputs.get(timeout=5.0)
            whole = hub.inbox.feed(payload, attachment)
            if whole is not None:
                came.append((time.monotonic(), SpikeBatch.decode(whole)))
        counters = hub.counters()["device"]
    *parts, (_, batch) = came
    during = [part for t, part in parts if t < sent + period_s]
    if stream_spikes_ms:
        assert sum(part.channel.size for part in during) > 10
        assert counters["spike_parts_sent"] == len(parts)
    else:
        assert not parts and counters["spike_parts_sent"] == 0
    assert all(part.step == batch.step == 0 for _, part in parts)
    spikes = merge_parts([part for _, part in parts], batch)
    assert spikes.channel.size > 10 and 0 <= spikes.t_ms.min() <= spikes.t_ms.max() < 500


def test_a_negative_amplitude_is_refused_not_taken_past_the_charge_limit():
    """An MEA pulse's amplitude is its size (the polarity is ``safety.polarity``): a
    negative one is refused, not let past the amplitude and charge checks (-100 µA for
    300 µs is 30 nC, over a 10 µm electrode's 18 nC) and written to the instrument."""
    gate = SafetyGate(PulseLimits(electrode_diameter_um=10.0))
    assert gate.admit(2, -100.0, 0.6, 0.0).startswith("amplitude")
    assert gate.admit(2, -1.0, 0.4, 0.0).startswith("amplitude")
    assert gate.refused == {"amplitude": 2} and gate.admitted == 0


def test_a_pulse_on_an_electrode_the_layout_lacks_is_refused_and_counted(emulators):
    """A channel beyond the layout is refused by reason (``channel``), never sent, and the
    endpoint serves on: before, one due at once ended the endpoint with an IndexError, and
    one due later killed the thread that fires pulses and samples the clock, silently."""
    from hub.protocol import Stimulation

    emu = emulators()
    with conformance.served(lambda: endpoint_for(emu)) as hub:
        # 100 ms steps: a pulse 50 ms into a step is due after its input came
        assert hub.start(mode="realtime", period_ms=100.0).ok
        n = hub.description.channel.size
        for step, (channel, onset_ms) in enumerate([(n, 0.0), (n + 500, 50.0)]):
            bad = Stimulation(**hub.window(step).stamp, channel=[channel], amplitude_ua=[10.0],
                              width_ms=[0.4], onset_ms=[onset_ms])  # fmt: skip
            hub.send(bad)
            assert hub.reply().step == step
        # a later pulse at a later onset is still fired: the firing thread lives on
        good = Stimulation(**hub.window(2).stamp, channel=[3], amplitude_ua=[10.0],
                           width_ms=[0.4], onset_ms=[50.0])  # fmt: skip
        hub.send(good)
        assert hub.reply().step == 2
        wait_for(lambda: len(emu.triggers) == 1, 5.0)
        assert emu.triggers[0][1] == [3]
        counters = hub.counters()
        assert counters["device"]["pulses_refused"] == {"channel": 2}
        assert counters["device"]["pulses_admitted"] == 1
        assert hub.error is None


def test_the_instrument_gone_mid_run_ends_the_endpoint_with_its_fault(emulators):
    """The RHX software gone mid-run ends the endpoint with the fault raised, as a
    :class:`DeviceFault` (``neuvision endpoint``: exit status 2, the fault named), not as a
    clean stop (it returned 0: a script or a supervisor saw a run that went well)."""
    from hub.endpoint import DeviceFault

    emu = emulators()
    with conformance.served(lambda: endpoint_for(emu)) as hub:
        assert hub.start(mode="realtime").ok
        hub.step(0)
        emu.stop()
        hub.thread.join(10.0)
        assert not hub.thread.is_alive(), "the endpoint kept serving a lost instrument"
        assert isinstance(hub.error, DeviceFault) and "RHX" in str(hub.error)
        assert hub.status is None
        hub.error = None  # the fault expected, seen


def test_the_spike_port_alone_lost_mid_run_ends_the_endpoint(emulators):
    """The spike stream lost while the command port still answers: before, the reader
    noted the fault and the run went on with no spike ever again, its pulses dropped
    unsaid."""
    import socket

    from hub.endpoint import DeviceFault

    emu = emulators()
    with conformance.served(lambda: endpoint_for(emu)) as hub:
        assert hub.start(mode="realtime").ok
        hub.step(0)
        for conn in list(emu._spike_clients):
            conn.shutdown(socket.SHUT_RDWR)
        hub.thread.join(10.0)
        assert not hub.thread.is_alive(), "the endpoint kept serving without its spikes"
        assert isinstance(hub.error, DeviceFault) and "spike port" in str(hub.error)
        hub.error = None  # the fault expected, seen


def test_a_worker_that_fails_ends_the_endpoint_as_a_fault(emulators, monkeypatch):
    """Anything a pulse's delivery raises beyond the instrument's own faults (a bug) ends
    the endpoint, named; before, it ended the thread that fires pulses and samples the
    clock, and the endpoint served on with neither."""
    from hub.endpoint import DeviceFault
    from hub.protocol import Stimulation

    emu = emulators()
    endpoint = endpoint_for(emu)

    def broken(pulses):
        raise RuntimeError("a bug in deliver")

    with conformance.served(lambda: endpoint) as hub:
        monkeypatch.setattr(endpoint.driver, "deliver", broken)
        assert hub.start(mode="realtime", period_ms=100.0).ok
        later = Stimulation(**hub.window(0).stamp, channel=[3], amplitude_ua=[10.0],
                            width_ms=[0.4], onset_ms=[50.0])  # fmt: skip
        hub.send(later)
        hub.thread.join(10.0)
        assert not hub.thread.is_alive(), "the endpoint served on without its worker"
        assert isinstance(hub.error, DeviceFault) and "a bug in deliver" in str(hub.error)
        assert not endpoint.driver.enabled
        hub.error = None  # the fault expected, seen


def test_the_first_fault_is_the_one_the_endpoint_ends_with(emulators):
    """What follows a fault (spikes streamed on the session its stop closed: a full suite
    saw ``ZError('session closed')`` raised in place of the bug) does not replace it."""
    from hub.endpoint import DeviceFault

    endpoint = endpoint_for(emulators())
    first = DeviceFault("the endpoint's device worker failed: RuntimeError('a bug')")
    endpoint._failed(first)
    endpoint._failed(DeviceFault("streaming spikes failed: ZError('session closed')"))
    assert endpoint.driver.fault is first


def test_the_stop_guard_disables_every_electrode_when_the_adapter_is_gone(emulator, capfd):
    """The adapter's process ended without making the instrument safe (SIGKILL, the OOM
    killer): the RHS kept its last pulse's electrodes enabled, on the trigger key, in run
    mode. The stop guard, which shares the command port, disables and uploads every
    electrode and stops run mode; released by a clean close, it writes nothing."""
    driver = driver_for(emulator)
    driver.open()
    driver.start()
    driver.deliver([BiphasicPulse(3, 20.0, 100.0, True), BiphasicPulse(7, 20.0, 100.0, True)])
    names = [emulator.layout.names[c] for c in (3, 7)]
    wait_for(lambda: len(emulator.triggers) == 1, 5.0)  # the uploads came before it
    assert all(emulator.uploaded[n]["stimenabled"] == "true" for n in names)
    assert driver.guard is not None and driver.guard.process.poll() is None
    driver.guard.abandon()  # as the process's end closes its pipe: no release
    assert driver.guard.process.wait(timeout=5) == 0
    assert "stop guard: the adapter of the RHX at 127.0.0.1" in capfd.readouterr().err
    wait_for(lambda: emulator.values["runmode"] == "stop", 5.0)
    for name in emulator.layout.names:
        assert emulator.values[f"{name}.stimenabled"] == "false"
        assert emulator.uploaded[name].get("stimenabled", "false") == "false", name
    driver.close()

    released = driver_for(emulator)
    released.open()
    released.start()
    guard = released.guard.process
    released.close()  # disables what it enabled, stops run mode, then releases the guard
    assert guard.wait(timeout=5) == 0
    assert "stop guard" not in capfd.readouterr().err  # it wrote nothing


def test_a_command_the_rhx_does_not_answer_ends_the_port_and_the_guard_writes_the_stop(
    emulator, caplog
):
    """The instrument froze: a command timed out, and the driver went on using the port
    for a second per command while closing (the run ended ~5 s after the freeze), then took
    the instrument's late answers for its next commands' ("the instrument holds
    '71.8748'"). A port that failed is not used again; at close its stop guard writes the
    stop on it, read when the instrument answers again."""
    driver = driver_for(emulator)
    driver.open()
    driver.start()
    driver.deliver([BiphasicPulse(3, 20.0, 100.0, True)])
    name = emulator.layout.names[3]
    wait_for(lambda: len(emulator.triggers) == 1, 5.0)
    emulator.faults.stall_until = time.monotonic() + 2.0
    with pytest.raises(RhxError, match="RHX command port: timed out"):
        driver.stop()
    t0 = time.monotonic()
    with pytest.raises(RhxError, match=r"failed earlier \(timed out\): not used again"):
        driver.stop()
    driver.close()
    assert time.monotonic() - t0 < 0.5  # no more seconds spent on a dead port
    assert "the stop guard writes the stop on it" in caplog.text
    wait_for(lambda: emulator.values["runmode"] == "stop", 5.0)  # once it answers again
    assert emulator.values[f"{name}.stimenabled"] == "false"
    assert emulator.uploaded[name]["stimenabled"] == "false"


def test_an_open_that_fails_past_the_handshake_leaves_the_rhx_safe_and_says_why(emulator, capfd):
    """The spike port wrong (a lab's typo): the failure raised is the port's, the
    instrument is left with every electrode disabled and run mode stopped, and the stop
    guard is released, not fired (its line would hide the cause)."""
    with socket.socket() as spare:  # a port nobody listens on
        spare.bind(("127.0.0.1", 0))
        wrong = spare.getsockname()[1]
    driver = RhxDriver(emulator.layout, command_port=emulator.command_port, spike_port=wrong)
    with pytest.raises(RhxError, match=f"cannot reach the RHX software at 127.0.0.1:{wrong}"):
        driver.open()
    assert driver.guard is not None and driver.guard.process.wait(timeout=5) == 0
    assert "stop guard" not in capfd.readouterr().err
    assert emulator.values["runmode"] == "stop"
    assert all(emulator.values[f"{n}.stimenabled"] == "false" for n in emulator.layout.names)


def test_a_service_that_is_not_the_rhx_is_sent_nothing_but_the_first_question():
    """The command port pointed at another program: it is asked its sample rate, and when
    the answer is not an RHX's, nothing else (no guard's stop commands) is written to it."""
    with socket.create_server(("127.0.0.1", 0)) as server:
        received = []

        def answer() -> None:
            conn, _ = server.accept()
            with conn:
                received.append(conn.recv(4096))
                conn.sendall(b"Return: sampleratehertz hello\n")
                conn.settimeout(1.0)
                try:
                    while chunk := conn.recv(4096):
                        received.append(chunk)
                except TimeoutError:
                    pass

        thread = threading.Thread(target=answer)
        thread.start()
        port = server.getsockname()[1]
        driver = RhxDriver(ElectrodeLayout.mcs60(), command_port=port, spike_port=port)
        with pytest.raises(RhxError, match="does not answer as the RHX software"):
            driver.open()
        thread.join(timeout=5)
    assert b"".join(received) == b"get sampleratehertz\n" and driver.guard is None


def test_a_second_client_of_one_instrument_is_refused_and_changes_nothing(emulator):
    """Two runs pointed at one RHX: the software serves one command client at a time, so
    the second cannot reach the instrument (its first question unanswered) and the first
    run's settings stand."""
    first = driver_for(emulator)
    first.open()
    first.start()
    second = RhxDriver(
        emulator.layout,
        command_port=emulator.command_port,
        spike_port=emulator.spike_port,
        timeout_s=0.5,
    )
    try:
        with pytest.raises(RhxError, match="serves one client at a time"):
            second.open()
        assert emulator.values["runmode"] == "run"  # the first run's, untouched
        first.sample_clock()  # the first still talks to it
    finally:
        second.close()
        first.close()
