"""The MEA adapter's LSL driver with real pylsl on loopback (tests/conftest.py points LSL at
adapters/mea/lsl_loopback.cfg): spikes from an outlet made here, binned by step through the
real endpoint on a real Zenoh session; stimulation markers read by an inlet made here;
safety, record-only, a lost stream, and the driver's settings."""

from __future__ import annotations

import json
import secrets
import time

import numpy as np
import pylsl
import pytest

from adapters.mea.endpoint import MeaEndpoint
from adapters.mea.layout import ElectrodeLayout
from adapters.mea.lsl import LslDriver
from adapters.mea.safety import PulseLimits
from hub import conformance
from hub.config import ConfigError, load_config
from hub.protocol import Stimulation
from tests.harness import wait_for

LAYOUT = ElectrodeLayout.mcs60()


def unique(what: str) -> str:
    """A stream name no other test (or test run) uses."""
    return f"nv-test-{what}-{secrets.token_hex(4)}"


class SpikeSource:
    """An instrument's spike outlet: one sample per spike, the electrode in channel 0."""

    def __init__(self, fmt: str = "string"):
        self.name, self.fmt = unique("spikes"), fmt
        info = pylsl.StreamInfo(self.name, "Spikes", 1, pylsl.IRREGULAR_RATE, fmt, self.name)
        self.outlet = pylsl.StreamOutlet(info)

    def spike(self, channel: int, lsl_t: float) -> None:
        value = LAYOUT.names[channel] if self.fmt == "string" else channel
        self.outlet.push_sample([value], lsl_t)

    def close(self) -> None:
        self.outlet = None  # destroyed: inlets reading it see it lost


@pytest.fixture
def source():
    src = SpikeSource()
    yield src
    src.close()


class Stimulator:
    """The lab's stimulator program: reads the endpoint's marker outlet."""

    def __init__(self, name: str, timeout_s: float = 10.0):
        found = pylsl.resolve_bypred(f"name='{name}' and type='Markers'", 1, timeout_s)
        assert found, f"no marker outlet {name!r}"
        self.inlet = pylsl.StreamInlet(found[0], recover=False)
        self.inlet.open_stream(timeout_s)
        self.markers: list[tuple[dict, float]] = []

    def stops(self) -> int:
        """How many ``stop`` markers have come so far."""
        while (got := self.inlet.pull_sample(0.0))[0] is not None:
            self.markers.append((json.loads(got[0][0]), got[1]))
        return sum(m["kind"] == "stop" for m, _ in self.markers)

    def pulses(self, n: int, timeout_s: float = 10.0) -> list[tuple[dict, float]]:
        """Wait for ``n`` pulse markers in all (JSON, LSL timestamp)."""
        deadline = time.monotonic() + timeout_s
        while sum(m["kind"] == "pulse" for m, _ in self.markers) < n:
            assert time.monotonic() < deadline, f"markers so far: {self.markers}"
            sample, t = self.inlet.pull_sample(0.05)
            if sample is not None:
                self.markers.append((json.loads(sample[0]), t))
        return [(m, t) for m, t in self.markers if m["kind"] == "pulse"]


def lsl_endpoint(source: SpikeSource, stim_outlet: str = "", **limits) -> MeaEndpoint:
    driver = LslDriver(LAYOUT, source.name, stim_outlet=stim_outlet, stim_wait_s=10.0)
    return MeaEndpoint(driver, PulseLimits(**limits), reply_margin_ms=1.0)


# ---------------------------------------------------------------- the driver alone


@pytest.mark.parametrize("fmt", ["string", "int32"])
def test_spikes_come_by_electrode_at_their_lsl_time(fmt):
    src = SpikeSource(fmt)
    d = LslDriver(LAYOUT, src.name)
    d.open()
    try:
        d.start()
        now = pylsl.local_clock()
        sent = [(5, now - 0.010), (59, now - 0.005), (0, now)]
        for channel, t in sent:
            src.spike(channel, t)
        src.outlet.push_sample(["zz-999" if fmt == "string" else 60], now)  # no such electrode
        got = ([], [], [])
        while len(got[0]) < len(sent):
            wait_for(lambda: d._spikes, 5.0)
            for part, new in zip(got, d.take_spikes(), strict=True):
                part.extend(new.tolist())
        channel, inst_s, arrived = map(np.array, got)
        assert channel.tolist() == [c for c, _ in sent]
        assert np.allclose(inst_s, [t for _, t in sent], atol=1e-9)  # the instrument's stamps
        wait_for(lambda: d.counts["unknown_channel"] == 1, 5.0)
        # the same machine: LSL's clock is time.monotonic()'s, the correction about 0
        report = d.report()
        assert abs(report["lsl_time_correction_s"]) < 1e-3
        assert abs(report["clock_offset_s"] - (pylsl.local_clock() - time.monotonic())) < 1e-3
        local = d.clock.to_local(inst_s)
        assert np.all(local <= arrived + 1e-3)  # a spike is seen after it happened
    finally:
        d.close()
        src.close()


def test_a_float_spike_stream_is_refused_when_opened():
    name = unique("float")
    info = pylsl.StreamInfo(name, "Spikes", 1, pylsl.IRREGULAR_RATE, "float32", name)
    outlet = pylsl.StreamOutlet(info)  # noqa: F841 (kept alive while resolved)
    d = LslDriver(LAYOUT, name)
    with pytest.raises(Exception, match="must name the electrode"):
        d.open()


def test_no_spike_stream_is_a_named_fault():
    d = LslDriver(LAYOUT, unique("absent"), resolve_timeout_s=0.5)
    with pytest.raises(Exception, match="no LSL spike stream matching name='nv-test-absent"):
        d.open()


# ---------------------------------------------------------------- through the endpoint


def test_spikes_are_binned_by_step_and_a_late_one_goes_in_the_next_batch(source):
    period_ms = 40.0

    def run_ms(t0_s: float, t_ms: float) -> float:
        return t0_s * 1e3 + float(t_ms)

    with conformance.served(lambda: lsl_endpoint(source)) as hub:
        assert hub.start(mode="realtime", n_steps=60, period_ms=period_ms).ok
        lsl_t0 = pylsl.local_clock()  # run time 0 is a little later: when step 0's input arrives
        hub.send(hub.valid_input(0))
        # spikes in the middle of windows 1 and 3, sent ahead of their time: the input's trip
        # (a few ms on a loaded machine) moves run time 0 but not the windows they fall in
        source.spike(5, lsl_t0 + 1.5 * period_ms / 1e3)
        source.spike(7, lsl_t0 + 3.5 * period_ms / 1e3)
        source.spike(9, lsl_t0 + 3.5 * period_ms / 1e3 + 0.001)
        batches = {}
        for k in range(1, 4):
            batches[k - 1] = hub.reply()
            hub.send(hub.valid_input(k))
        batches[3] = hub.reply()
        assert [b.step for b in batches.values()] == [0, 1, 2, 3]
        assert batches[0].channel.size == 0 and batches[2].channel.size == 0
        assert batches[1].channel.tolist() == [5]
        assert batches[3].channel.tolist() == [7, 9]
        first_ms = run_ms(batches[1].t0_s, batches[1].t_ms[0])
        trip_ms = 1.5 * period_ms - first_ms  # run time 0 after lsl_t0
        assert -1.0 < trip_ms < period_ms / 4
        # the instrument's spacing is kept to well under a millisecond
        assert run_ms(batches[3].t0_s, batches[3].t_ms[0]) - first_ms == pytest.approx(
            2 * period_ms, abs=0.5
        )
        assert batches[3].t_ms[1] - batches[3].t_ms[0] == pytest.approx(1.0, abs=0.1)
        # a spike of window 1 that arrives now: in a later batch, at its true time, counted
        source.spike(11, lsl_t0 + 1.6 * period_ms / 1e3)
        late = None
        for k in range(4, 60):
            hub.send(hub.valid_input(k))
            batch = hub.reply()
            if batch.late_channel is not None:
                late = batch
                break
        assert late is not None, "the late spike never came"
        assert late.late_channel.tolist() == [11] and late.channel.size == 0
        late_ms = run_ms(late.t0_s, late.late_t_ms[0])  # its true run time
        assert late_ms - first_ms == pytest.approx(0.1 * period_ms, abs=0.5)
        device = hub.counters()["device"]
        assert device["late_spikes"] == 1
        assert abs(device["clock_drift_ppm"]) < 1000 and "clock_offset_s" in device


def test_stimulation_markers_match_the_pulses_and_unsafe_ones_never_leave(source):
    outlet = unique("stim")
    # 10 µm electrodes: 18 nC per phase at most
    with conformance.served(
        lambda: lsl_endpoint(source, outlet, electrode_diameter_um=10.0)
    ) as hub:
        stimulator = Stimulator(outlet)
        # 40 ms windows, pulses 30 ms into them: an input (sent once the previous window's
        # reply is here) comes before its pulse is due unless this machine is slow
        period_ms, onset_ms = 40.0, 30.0
        assert hub.start(mode="realtime", period_ms=period_ms).ok
        w0 = hub.window(0)
        # within the described limits, over the electrode's safe charge: refused
        hub.send(Stimulation(**w0.stamp, channel=[2], amplitude_ua=[100.0], width_ms=[0.4],
                             onset_ms=[1.0]))  # fmt: skip
        assert hub.reply().step == 0
        w1 = hub.window(1)
        hub.send(Stimulation(**w1.stamp, channel=[3, 8], amplitude_ua=[40.0, 60.0],
                             width_ms=[0.3, 0.2], onset_ms=[onset_ms, onset_ms]))  # fmt: skip
        assert hub.reply().step == 1
        replied = [time.monotonic()]  # each input had come by its reply
        w2 = hub.window(2)
        hub.send(Stimulation(**w2.stamp, channel=[12], amplitude_ua=[20.0], width_ms=[0.4],
                             onset_ms=[onset_ms]))  # fmt: skip
        assert hub.reply().step == 2
        replied.append(time.monotonic())
        pulses = stimulator.pulses(3)
        markers = [m for m, _ in pulses]
        assert [m["channel"] for m in markers] == [3, 8, 12]  # the refused one never left
        assert [m["electrode"] for m in markers] == [LAYOUT.names[c] for c in (3, 8, 12)]
        assert [m["amplitude_ua"] for m in markers] == [40.0, 60.0, 20.0]
        assert [m["phase_us"] for m in markers] == pytest.approx([150.0, 100.0, 200.0])
        assert {m["polarity"] for m in markers} == {"negative_first"}
        assert {m["shape"] for m in markers} == {"biphasic"} and markers[0]["v"] == 1
        assert markers[0]["trigger"] == markers[1]["trigger"] < markers[2]["trigger"]
        # each trigger at its onset into the run (run time 0: when step 0's input came), as
        # LSL stamped it: never before it was due, and no later than the endpoint counted it
        # fired (its lag: a fraction of a ms idle, a few ms loaded, partly after the stamp).
        # The lag counts from the input's arrival when that came after the onset (a reply
        # late here on a loaded machine): the input had come by the time its reply was here.
        lags_ms = list(hub.endpoint.trigger_lag_ms)
        assert len(lags_ms) == 2 and max(lags_ms) < 50.0, lags_ms
        run_t0 = hub.endpoint.run_origin_s
        for (_, stamp), w, by, lag_ms in zip(pulses[1:], (w1, w2), replied, lags_ms, strict=True):
            due = run_t0 + w.t0_s + onset_ms / 1e3
            fired_by = max(due, by) + (lag_ms + 0.5) / 1e3
            assert due - 1e-5 <= stamp <= fired_by, ((stamp - due) * 1e3, lags_ms)
        assert pulses[0][1] == pulses[1][1]  # one trigger, one stamp
        device = hub.counters()["device"]
        assert device["pulses_refused"] == {"charge": 1}
        assert device["pulses_admitted"] == 3 and device["pulses"] == 3
        assert device["stimulator"] == outlet and "pulses_unheard" not in device
        stops = stimulator.stops()
        assert hub.end().ok  # the run's end tells the stimulator to stop
        wait_for(lambda: stimulator.stops() > stops)


def test_record_only_refuses_every_pulse_and_counts_it(source):
    endpoint = lsl_endpoint(source, stim_outlet="")
    with conformance.served(lambda: endpoint) as hub:
        assert hub.start(mode="realtime").ok
        w = hub.window(0)
        hub.send(Stimulation(**w.stamp, channel=[1, 2], amplitude_ua=[10.0, 10.0],
                             width_ms=[0.2, 0.2], onset_ms=[0.0, 1.0]))  # fmt: skip
        assert hub.reply().step == 0
        device = hub.counters()["device"]
        assert device["pulses_refused"] == {"record_only": 2}
        assert device["pulses_admitted"] == 0 and "triggers" not in device
        assert device["stimulator"] == "none (record-only)"
        assert endpoint.driver._outlet is None  # nothing to send through


@pytest.mark.parametrize("check", conformance.CHECKS, ids=lambda c: c.__name__)
def test_the_lsl_mea_endpoint_keeps_the_contract(check, source):
    check(lambda: lsl_endpoint(source))


def test_the_spike_stream_lost_mid_run_ends_the_endpoint(source):
    endpoint = lsl_endpoint(source)
    with conformance.served(lambda: endpoint) as hub:
        assert hub.start(mode="realtime").ok
        hub.step(0)
        source.close()
        wait_for(lambda: endpoint.driver.fault is not None, 20.0)
        assert "lost" in str(endpoint.driver.fault)
        hub.thread.join(10.0)
        assert not hub.thread.is_alive(), "the endpoint kept serving a lost instrument"
        # ended by the fault, raised (``neuvision endpoint``: exit status 2), not a clean stop
        assert hub.error is endpoint.driver.fault
        hub.error = None  # the fault expected, seen


# ---------------------------------------------------------------- settings


def lsl_config(*more: str):
    return load_config(None, ['culture.kind="mea"', 'loop.mode="realtime"',
                              "loop.deadline_ms=18", 'culture.params.driver="lsl"',
                              *more])  # fmt: skip


@pytest.mark.parametrize(
    "override, named",
    [
        ('culture.params.stim_outlett="x"', r"unknown key\(s\) \['stim_outlett'\]"),
        ('culture.params.host="127.0.0.1"', r"unknown key\(s\) \['host'\].*driver 'lsl'"),
        ("culture.params.resolve_timeout_s=-1", "culture.params.resolve_timeout_s"),
        ("culture.params.stim_wait_s=0", "culture.params.stim_wait_s"),
        ("culture.params.spike_stream=3", "culture.params.spike_stream"),
        ('culture.params.spike_type=""', "culture.params.spike_stream: the LSL spike stream"),
        ('culture.params.stim_outlet="it\'s"', "culture.params.stim_outlet may not hold a quote"),
    ],
)
def test_bad_lsl_settings_name_the_key(override, named):
    cfg = lsl_config(override)
    with pytest.raises(ConfigError, match=named):
        MeaEndpoint.check_config(cfg.culture, cfg)


def test_lsl_settings_make_an_lsl_driver_and_open_nothing():
    cfg = lsl_config('culture.params.spike_stream="rig"', 'culture.params.stim_outlet="stim"')
    endpoint = MeaEndpoint.from_config(cfg.culture, cfg)
    assert isinstance(endpoint.driver, LslDriver) and endpoint.driver.stimulates
    assert endpoint.driver.query == "name='rig' and type='Spikes'"
    assert endpoint.driver._inlet is None
