"""The hub's loop over real Zenoh, with endpoints in separate processes on loopback.

Each test gets its own session name and port (see conftest), so runs never cross.
"""

from __future__ import annotations

import os
import signal
import threading
import time

import msgpack
import numpy as np
import pytest
import zenoh

from hub import wire
from hub.bus import BusError, open_session, payload_bytes
from hub.config import load_config
from hub.loop import Hub
from hub.protocol import (
    SCHEMA_VERSION,
    ControlReply,
    ControlRequest,
    Description,
    HubStatus,
    MotorCommand,
    SensorReading,
    SpikeBatch,
    StepWindow,
    Stimulation,
)
from hub.record import read_manifest
from hub.scheduling import PM_QOS_DEVICE
from tests.harness import harness, subscribed, wait_for

pytestmark = pytest.mark.bus


def test_lockstep_keeps_the_step_order_with_one_step_of_latency(tmp_path, bus_overrides):
    with harness(tmp_path, bus_overrides, "experiment.duration_s=0.5") as h:
        result = h.run()
    assert result.outcome == "completed" and result.steps == 50
    assert result.counts["dropped"] == {} and result.counts["missing"] == {}
    motors, stims = h.sent(MotorCommand), h.sent(Stimulation)
    sensors, spikes = h.received(SensorReading), h.received(SpikeBatch)
    assert sorted(sensors) == sorted(stims) == sorted(spikes) == list(range(50))
    # Whatever ends a run, the hub's last word to the body is "stop" -- and the body's reply
    # to it (step 50, wheels at 0) says it applied it.
    assert sorted(motors) == list(range(51)) and motors[50] == MotorCommand.stop(motors[50].window)
    assert sorted(sensors) == list(range(50))
    (final,) = h.record.decoded(SensorReading, "final")  # kept apart from the run's data
    assert final.step == 50 and tuple(final.pose) == (50, 0.0, 0.0)
    # Step 0: zero motion, no stimulation.
    assert motors[0].left_mps == motors[0].right_mps == 0 and stims[0].n_pulses == 0
    for k in range(1, 50):
        # The motor command of step k is decoded from the spikes of step k-1 ...
        assert motors[k].left_mps == k - 1
        assert motors[k].right_mps == spikes[k - 1].channel.size
        # ... and the stimulation of step k is coded from the sensors of step k-1.
        assert stims[k].n_pulses == min(k - 1, 8)
        assert np.all(stims[k].amplitude_ua == k - 1)
        # The body replied for step k having applied the motor command of step k.
        assert tuple(sensors[k].pose) == (k, motors[k].left_mps, motors[k].right_mps)
        # The culture's spikes of step k answer the stimulation of step k.
        assert spikes[k].channel.size == stims[k].n_pulses
    assert h.exit_codes == {"body": 0, "culture": 0}
    assert h.record.manifest["outcome"] == "completed"
    assert h.record.manifest["counts"]["late"] == {}


def test_replies_are_taken_in_step_order_however_the_hubs_thread_is_held_up(
    tmp_path, bus_overrides, monkeypatch
):
    """On a busy machine the hub's thread may be preempted right after the first inputs go
    out: played here by holding it up in the put of the culture's first input (0.2 s, some
    hundred round trips). The culture's first reply, come meanwhile, is still taken before
    its second, which the body's first reply lets out: the record and the burst observer see
    the steps in order. (A CI run saw step 1 taken first, and the observer count step 0
    missing.)"""
    from hub.link import HubLink

    put = HubLink.send

    def put_held_at_the_first_stimulation(self, role, raw):
        put(self, role, raw)
        if role == "culture" and Stimulation.decode(raw).step == 0:
            time.sleep(0.2)

    monkeypatch.setattr(HubLink, "send", put_held_at_the_first_stimulation)
    with harness(tmp_path, bus_overrides, "experiment.duration_s=0.2", "online.enabled=true") as h:
        result = h.run()
    assert result.outcome == "completed" and result.steps == 20
    assert result.counts["late"] == {} and result.counts["missing"] == {}
    taken = [m.step for m in h.record.decoded(SpikeBatch, "rx")]  # in the order taken
    assert taken == list(range(20))
    assert result.counts["online_analysis"] == "complete"
    assert result.counts["online_steps_missing"] == 0


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity here")
def test_the_hub_and_each_endpoint_run_on_the_cpus_their_config_names(tmp_path, bus_overrides):
    cpus = sorted(os.sched_getaffinity(0))
    hub_cpu, endpoint_cpu = cpus[-1], cpus[0]  # one CPU each where there are two
    placement = [f"loop.cpus=[{hub_cpu}]", f"body.cpus=[{endpoint_cpu}]"]
    placement.append(f"culture.cpus=[{endpoint_cpu}]")
    with harness(tmp_path, bus_overrides, "experiment.duration_s=0.2", *placement) as h:
        result = h.run()
    assert result.outcome == "completed" and result.steps == 20
    manifest = h.record.manifest
    assert manifest["timing"]["cpus"] == [hub_cpu]
    assert manifest["endpoints"]["body"]["cpus"] == [endpoint_cpu]
    assert manifest["endpoints"]["culture"]["cpus"] == [endpoint_cpu]
    # The run over, this process's threads may run where they could before.
    assert sorted(os.sched_getaffinity(0)) == cpus


@pytest.mark.parametrize("keep", [True, False])
def test_the_record_says_whether_idle_cpus_were_kept_awake(tmp_path, bus_overrides, keep):
    with harness(
        tmp_path, bus_overrides, "experiment.duration_s=0.2", f"loop.keep_cpus_awake={keep}".lower()
    ) as h:
        result = h.run()
    assert result.outcome == "completed"
    manifest = h.record.manifest
    got = [manifest["timing"]["cpus_awake"]]
    got += [manifest["endpoints"][role]["cpus_awake"] for role in ("body", "culture")]
    if not keep:
        assert all(g == {"held": False, "reason": got[0]["reason"]} for g in got)
        assert "loop.keep_cpus_awake = false" in got[0]["reason"]
    elif os.access(PM_QOS_DEVICE, os.W_OK):  # the hub and each endpoint held the request
        assert got == [{"held": True, "latency_us": 0}] * 3
    else:
        assert all(not g["held"] and PM_QOS_DEVICE in g["reason"] for g in got)


def test_realtime_mode_holds_its_period(tmp_path, bus_overrides):
    with harness(
        tmp_path,
        bus_overrides,
        "loop.mode=realtime",
        "loop.period_ms=20",
        "experiment.duration_s=2",
    ) as h:
        result = h.run()
    t = result.timing
    assert result.outcome == "completed" and t["steps"] == 100
    # Anchored schedule: 100 periods of 20 ms take 2 s, not more (no drift).
    assert 1.98 <= t["wall_s"] < 2.0 + 0.2
    assert t["lateness_ms_median"] < 2.0
    assert result.counts["missing"] == {}
    # The record says how the hub's and the endpoints' threads were scheduled.
    hub_sched = h.record.manifest["timing"]["scheduling"]
    assert hub_sched == t["scheduling"]
    ends = h.record.manifest["endpoints"]
    if hub_sched["policy"] == "fifo":  # permitted here: hub at 10, endpoints two below
        assert hub_sched["priority"] == 10 and hub_sched["threads"] > 1
        assert {r: e["scheduling"]["priority"] for r, e in ends.items()} == {
            "body": 8,
            "culture": 8,
        }
    else:
        assert "refused" in hub_sched["reason"]
        assert all("refused" in e["scheduling"]["reason"] for e in ends.values())


def test_a_late_reply_is_counted_and_the_policy_stands_in(tmp_path, bus_overrides):
    with harness(
        tmp_path,
        bus_overrides,
        "loop.mode=realtime",
        "loop.period_ms=20",
        "experiment.duration_s=1.2",
        "body.params.late_every=10",  # the body sleeps 50 ms on steps 9, 19, ...
    ) as h:
        result = h.run()
    assert result.outcome == "completed"
    missed = sorted(
        e.payload["step"]
        for e in h.record.events
        if e.key == "missed" and e.payload["role"] == "body"
    )
    assert 9 in missed
    assert result.counts["late"]["body"] >= 1
    # Each reply that missed its deadline is counted once: late if it came after all,
    # missing if it never came.
    late, missing = result.counts["late"]["body"], result.counts["missing"].get("body", 0)
    assert late + missing == len(missed)
    stims = h.sent(Stimulation)
    for k in missed:
        if k + 1 in stims:
            # policy.missing_sensors = zero_stim: nothing is coded from a missing reading
            assert stims[k + 1].n_pulses == 0
    assert stims[min(set(range(2, 59)) - set(missed) - {k + 1 for k in missed})].n_pulses > 0


def test_in_lockstep_a_reply_owed_past_the_reply_timeout_is_replaced_by_the_policy(
    tmp_path, bus_overrides
):
    with harness(
        tmp_path,
        bus_overrides,
        "experiment.duration_s=0.3",
        "loop.reply_timeout_s=0.03",
        "body.params.late_every=10",  # the body sleeps 50 ms on steps 9, 19, ...
    ) as h:
        result = h.run()
    assert result.outcome == "completed" and result.steps == 30
    missed = [e.payload for e in h.record.events if e.key == "missed"]
    assert {m["step"] for m in missed if m["role"] == "body"} >= {9, 19}
    assert result.counts["late"]["body"] >= 2  # the replies came after all, and were counted
    # The culture's next stimulation waited on the late reading: no culture reply was owed.
    assert not [m for m in missed if m["role"] == "culture"]
    assert "culture" not in result.counts["late"]
    stims = h.sent(Stimulation)
    assert stims[10].n_pulses == stims[20].n_pulses == 0  # missing_sensors = zero_stim
    assert stims[9].n_pulses > 0
    assert sorted(h.received(SpikeBatch)) == list(range(30))


@pytest.mark.parametrize(
    "scheme, reason, last_stimulation",
    [
        ('coding.scheme="tests.endpoints:code_wrong_step_at_20"', "a Stimulation for step 20", 19),
        (
            'decoding.scheme="tests.endpoints:decode_fails_at_3"',
            "decoding.scheme tests.endpoints:decode_fails_at_3 raised at step 3: ZeroDivisionError",
            None,
        ),
    ],
)
def test_a_scheme_that_fails_ends_the_run_as_a_fault_with_the_robot_stopped(
    tmp_path, bus_overrides, scheme, reason, last_stimulation
):
    with harness(tmp_path, bus_overrides, scheme) as h:
        result = h.run()
    assert result.outcome == "fault"
    assert reason in result.reason
    assert h.record.manifest["outcome"] == "fault"
    if last_stimulation is not None:
        assert max(h.sent(Stimulation)) == last_stimulation  # the bad one never left
    last_motor = h.record.decoded(MotorCommand, "tx")[-1]
    assert last_motor.left_mps == last_motor.right_mps == 0
    assert h.exit_codes == {"body": 0, "culture": 0}


def test_killing_an_endpoint_ends_the_run_within_a_second(tmp_path, bus_overrides):
    killed = {}

    def kill_at_step_100(progress):
        if progress.step >= 100 and not killed:
            os.kill(h.pid("culture"), signal.SIGKILL)
            killed["t"] = time.monotonic()
            killed["t_ns"] = time.time_ns()

    with harness(tmp_path, bus_overrides, "experiment.duration_s=1000", "loop.status_hz=100") as h:
        result = h.run(progress=kill_at_step_100)
        ended = time.monotonic()
    assert killed, "the run never reached step 100"
    assert result.outcome == "fault"
    assert "culture/0 died" in result.reason
    assert ended - killed["t"] < 1.0
    # The record is readable up to the kill, and says what happened.
    rec = h.record
    dead = [e for e in rec.events if e.key == "dead" and e.payload["role"] == "culture"]
    assert dead and (dead[0].t_wall_ns - killed["t_ns"]) / 1e9 < 1.0
    assert rec.manifest["outcome"] == "fault" and "culture/0" in rec.manifest["reason"]
    steps = sorted(h.received(SpikeBatch))
    assert steps == list(range(len(steps))) and len(steps) >= 100
    # Fault policy: the robot is left stopped.
    last_motor = rec.decoded(MotorCommand, "tx")[-1]
    assert last_motor.left_mps == last_motor.right_mps == 0
    assert h.exit_codes["body"] == 0


GARBAGE = [
    b"",
    b"\xc1not msgpack",
    msgpack.packb([1, 2, 3]),
    msgpack.packb({"v": 99, "step": 5}),
    msgpack.packb({"v": SCHEMA_VERSION, "step": "five"}),
    msgpack.packb({"v": True, "step": 1, "left_mps": 0.0, "right_mps": 0.0}),
    os.urandom(64),
]


def _forged(run: str, step: int) -> dict[str, bytes]:
    """Well-formed messages of the current run (its id read off the bus) for a step to
    come: what a stranger who watches the bus can make, all but the seal."""
    w = StepWindow.of(run, step, 0.01)
    return {
        "motor": MotorCommand(**w.stamp, left_mps=0.5, right_mps=-0.5).encode(),
        "stim": Stimulation(
            **w.stamp, channel=[0], amplitude_ua=[1], width_ms=[1], onset_ms=[0]
        ).encode(),
        "sensors": SensorReading(
            step=step, run=run, t_s=w.t1_s, ranges_m=[0.1] * 3, pose=[9, 9, 9], contact=False
        ).encode(),
        "spikes": SpikeBatch(**w.stamp, channel=[1], t_ms=[1]).encode(),
    }


def _spray(bus, keys, rounds=3):
    """A stranger on the bus: learns the run's id from the hub's motor commands, then puts
    garbage and forged messages (unsealed, or sealed with a key of its own) on every loop
    key, and garbage queries on the control key. Returns what it put on each key."""
    session = open_session(bus, listener=False)
    seen: list[MotorCommand] = []
    # sealing is not secrecy: the map before the seal is plain msgpack
    watcher = session.declare_subscriber(
        keys.motor("0"),
        lambda s: seen.append(MotorCommand.decode(payload_bytes(s)[: -wire.SEAL_BYTES])),
    )
    try:
        wait_for(lambda: len(seen) > 0)
        watcher.undeclare()
        run, step = seen[-1].run, seen[-1].step
        targets = {
            "motor": keys.motor("0"),
            "stim": keys.stim("0"),
            "sensors": keys.sensors("0"),
            "spikes": keys.spikes("0"),
        }
        sent = dict.fromkeys(targets, 0)
        own_key = wire.new_key()  # seals with a key that is not the run's
        for r in range(rounds):
            forged = _forged(run, step + 1 + r)
            for name, key in targets.items():
                for raw in GARBAGE:
                    session.put(key, raw, congestion_control=zenoh.CongestionControl.BLOCK)
                ((sealed, _),) = wire.frames(forged[name], own_key, r)
                session.put(key, sealed)
                session.put(key, forged[name])  # unsealed
                sent[name] += len(GARBAGE) + 2
        for key in (keys.potentials("0"), keys.hub_status, keys.alive("body", "0")):
            for raw in GARBAGE:
                session.put(key, raw)
        replies = []
        for raw in GARBAGE[:6]:
            for reply in session.get(keys.hub_control, payload=raw, timeout=5):
                replies.append(ControlReply.decode(payload_bytes(reply.ok)))
        # The endpoints report what they dropped in their descriptions.
        counters = {}

        def counted_all():
            for role in ("body", "culture"):
                for raw in wire.get(session, keys.describe(role, "0"), timeout_s=5):
                    counters[role] = Description.decode(raw).counters["dropped"]
            return (
                counters.get("body", {}).get("foreign", 0) >= sent["motor"]
                and counters.get("culture", {}).get("foreign", 0) >= sent["stim"]
            )

        wait_for(counted_all)
        return sent, replies, counters
    finally:
        session.close()


@pytest.mark.parametrize(
    "mode",
    [
        "lockstep",
        pytest.param("realtime", marks=pytest.mark.slow),  # the lockstep case is the same path
    ],
)
def test_a_stranger_on_the_bus_is_never_taken_for_the_hub_or_an_endpoint(
    tmp_path, bus_overrides, mode
):
    out = {}

    # The body takes 5 ms a step, so that the run (3 s or more) outlasts the spraying.
    slow = "body.params.delay_ms=5"
    with harness(
        tmp_path,
        bus_overrides,
        "experiment.duration_s=6",
        "loop.status_hz=50",
        slow,
        f'loop.mode="{mode}"',
    ) as h:
        bus, keys = h.cfg.bus, h.cfg.bus.keys

        def spray():
            out["sent"], out["replies"], out["counters"] = _spray(bus, keys)

        sprayer = threading.Thread(target=spray)

        def start_spraying(progress):
            if progress.step >= 20 and "started" not in out:
                out["started"] = True
                sprayer.start()

        result = h.run(progress=start_spraying)
        sprayer.join(timeout=30)
    assert out.get("started"), "garbage was never sent"
    sent, counters = out["sent"], out["counters"]
    assert result.outcome == "completed" and result.steps == 600
    # Everything the stranger put on a reply key was refused as foreign, counted exactly.
    dropped = result.counts["dropped"]
    assert dropped["body"] == {"foreign": sent["sensors"]}
    assert dropped["culture"] == {"foreign": sent["spikes"]}
    assert sum(dropped["control"].values()) == 6
    assert all(not r.ok for r in out["replies"]) and len(out["replies"]) == 6
    # The endpoints refused every input it sent, and stepped only on the hub's.
    assert counters["body"] == {"foreign": sent["motor"]}
    assert counters["culture"] == {"foreign": sent["stim"]}
    # Nothing of the stranger's was taken: every step's reply is the endpoint's own.
    # On a loaded machine a realtime reply may miss its deadline: it is then recorded as late
    # (and counted), never replaced by the stranger's.
    sensors = h.received(SensorReading)
    late = {m.step: m for m in h.record.decoded(SensorReading, "late")}
    assert sorted({**sensors, **late}) == list(range(600))
    assert len(late) == result.counts["late"].get("body", 0)
    sensors.update(late)
    motors = h.sent(MotorCommand)
    assert all(
        tuple(sensors[k].pose)[1:] == (motors[k].left_mps, motors[k].right_mps) for k in sensors
    )
    assert len(h.record.drops) == sent["sensors"] + sent["spikes"] - 2 * 3  # b"" not stored


def _control(session, keys, cmd):
    for reply in session.get(keys.hub_control, payload=ControlRequest(cmd=cmd).encode(), timeout=5):
        return ControlReply.decode(payload_bytes(reply.ok))
    raise AssertionError(f"no reply to {cmd}")


def test_each_endpoint_s_reply_round_trip_is_measured_live_and_in_the_manifest(
    tmp_path, bus_overrides
):
    statuses: list[HubStatus] = []
    with harness(
        tmp_path,
        bus_overrides,
        'loop.mode="realtime"',
        "experiment.duration_s=1",
        "loop.status_hz=20",
        "body.params.delay_ms=3",  # the body takes 3 ms to answer
    ) as h:
        runner = threading.Thread(target=h.run)
        runner.start()
        session = open_session(h.cfg.bus, listener=False)  # waits for the hub to be up
        watch = session.declare_subscriber(
            h.cfg.bus.keys.hub_status,
            lambda s: statuses.append(HubStatus.decode(payload_bytes(s))),
        )
        runner.join(timeout=60)
        watch.undeclare()
        session.close()
    assert h.result.outcome == "completed"
    rtt = h.record.manifest["timing"]["round_trip_ms"]
    assert set(rtt) == {"body", "culture"}
    assert 3.0 <= rtt["body"]["median"] <= rtt["body"]["p99"] <= rtt["body"]["max"]
    assert rtt["culture"]["median"] < rtt["body"]["median"]  # the echo culture answers at once
    live = [s.extra["round_trip_ms"] for s in statuses if s.extra.get("round_trip_ms")]
    # an endpoint's figure appears with its first reply: a status sent between the echo
    # culture's first reply and the body's has the culture's alone
    body_ms = [r["body"] for r in live if "body" in r]
    assert body_ms and all(ms >= 3.0 for ms in body_ms)


def test_pause_resume_stop_and_config_over_the_control_key(tmp_path, bus_overrides):
    statuses: list[HubStatus] = []
    out = {}

    with harness(
        tmp_path,
        bus_overrides,
        "loop.mode=realtime",
        "experiment.duration_s=100",
        "loop.status_hz=20",
    ) as h:
        bus, keys = h.cfg.bus, h.cfg.bus.keys

        def operator():
            session = open_session(bus, listener=False)
            sub = session.declare_subscriber(
                keys.hub_status, lambda s: statuses.append(HubStatus.decode(payload_bytes(s)))
            )
            try:
                wait_for(lambda: statuses and statuses[-1].step >= 20)
                out["pause"] = _control(session, keys, "pause")
                first = _control(session, keys, "status").data["step"]
                wait_for(lambda: statuses[-1].state == "paused")
                n = len(statuses)
                wait_for(lambda: len(statuses) >= n + 5)  # a quarter second of statuses
                out["paused_steps"] = (first, statuses[-1].step)
                out["pause_again"] = _control(session, keys, "pause")
                out["resume"] = _control(session, keys, "resume")
                wait_for(lambda: statuses[-1].step > first + 10)
                out["config"] = _control(session, keys, "config")
                out["stop"] = _control(session, keys, "stop")
            finally:
                sub.undeclare()
                session.close()

        thread = threading.Thread(target=operator)
        thread.start()
        result = h.run()
        thread.join(timeout=30)
    assert out["pause"].ok and out["pause"].state == "paused"
    first, later = out["paused_steps"]
    assert later <= first + 1  # nothing advanced while paused (the step in flight may finish)
    assert not out["pause_again"].ok and "while paused" in out["pause_again"].reason
    assert out["resume"].ok and out["resume"].state == "running"
    assert out["config"].data["loop"]["mode"] == "realtime"
    assert out["stop"].ok and out["stop"].state == "stopping"  # as pause and resume: the next
    assert out["stop"].data["extra"]["stop_reason"] == "stopped by control"  # and why
    assert out["resume"].data["extra"]["stop_reason"] == ""
    assert result.outcome == "stopped" and 30 < result.steps < 10_000
    # the time paused is wall time, not the run's pace: the realtime steps kept time
    timing = h.record.manifest["timing"]
    assert 0.25 <= timing["paused_s"] < timing["wall_s"]
    assert timing["x_realtime"] == pytest.approx(1.0, abs=0.1)
    assert any(s.alive == ["body/0", "culture/0", "hub/0"] for s in statuses)
    assert [e.payload["cmd"] for e in h.record.events if e.key == "control"] == [
        "pause",
        "status",
        "pause",
        "resume",
        "config",
        "stop",
    ]
    # The pause reached both endpoints at once (each made itself safe), and so did the resume.
    holds = [(e.key, e.payload) for e in h.record.events if e.key in ("hold", "unhold")]
    assert holds == [("hold", {"body": True, "culture": True}),
                     ("unhold", {"body": True, "culture": True})]  # fmt: skip
    assert h.record.manifest["endpoints"]["body"]["holds"] == 1
    (final,) = [e.payload for e in h.record.events if e.key == "final_stop"]
    assert final["acknowledged"]  # the body answered the final stop: it was applied


def test_status_is_published_at_status_hz_in_lockstep_too(tmp_path, bus_overrides):
    statuses: list[HubStatus] = []
    with harness(
        tmp_path, bus_overrides, "loop.status_hz=20", "experiment.duration_s=2",
        "loop.period_ms=10", "body.params.delay_ms=5",
    ) as h:  # fmt: skip

        def on_status(sample):
            statuses.append((time.monotonic(), HubStatus.decode(payload_bytes(sample))))

        with subscribed(h.cfg.bus, h.cfg.bus.keys.hub_status, on_status):
            result = h.run()
    assert result.outcome == "completed"
    assert result.timing["wall_s"] > 1.0  # 200 steps of a body that takes 5 ms each
    seen = [t for t, s in statuses if s.state == "running" and s.mode == "lockstep"]
    assert len(seen) >= 10
    rate_hz = (len(seen) - 1) / (seen[-1] - seen[0])
    assert 14 <= rate_hz <= 26  # 20 Hz asked, on a shared machine


@pytest.mark.slow  # waits out the hub's wait
def test_a_missing_endpoint_is_named_after_the_wait(tmp_path, bus_overrides):
    with harness(
        tmp_path, bus_overrides, 'culture.launch="external"', "loop.wait_timeout_s=5"
    ) as h:
        result = h.run()
    assert result.outcome == "fault"
    assert "culture/0 did not appear" in result.reason and "body" not in result.reason
    assert h.record.manifest["outcome"] == "fault"


def test_a_large_cultures_description_and_bursts_pass_the_loop(tmp_path, bus_overrides):
    # 100,000 channels (a 1.3 MB description) each firing 3 spikes a step: a 2.4 MB
    # SpikeBatch every step, over the default low-latency transport (one put carries at
    # most ~49 kB: the messages go in frames, hub/wire.py).
    with harness(
        tmp_path,
        bus_overrides,
        'culture.kind="tests.endpoints:LargeCulture"',
        "culture.params.n_channels=100000",
        "culture.params.spikes_per_step=300000",
        "online.enabled=false",
        "experiment.duration_s=0.1",
    ) as h:
        result = h.run()
    assert result.outcome == "completed" and result.steps == 10, result.reason
    assert result.counts["dropped"] == {} and result.counts["missing"] == {}
    assert h.record.descriptions()["culture"].channel.size == 100_000
    spikes = h.received(SpikeBatch)
    assert sorted(spikes) == list(range(10))
    assert all(b.channel.size == 300_000 for b in spikes.values())


def _stamps(record, kind, direction) -> dict[int, int]:
    """Each step's message of ``kind`` in ``direction``: the hub's wall clock stamp (ns)."""
    suffix = {MotorCommand: "/motor", SensorReading: "/sensors", Stimulation: "/stim",
              SpikeBatch: "/spikes"}[kind]  # fmt: skip
    return {
        kind.decode(f.payload).step: f.t_wall_ns
        for f in record.frames
        if f.direction == direction and f.key.endswith(suffix) and isinstance(f.payload, bytes)
    }


def test_an_input_is_stamped_before_its_put_so_never_after_its_reply(
    tmp_path, bus_overrides, monkeypatch
):
    # A put that returns late (the hub's thread preempted on a loaded machine): the echo
    # endpoints' replies are in before it returns.
    from hub.link import HubLink

    put = HubLink.send

    def put_returning_late(self, role, raw):
        put(self, role, raw)
        time.sleep(0.003)

    monkeypatch.setattr(HubLink, "send", put_returning_late)
    with harness(tmp_path, bus_overrides, "experiment.duration_s=0.3") as h:
        assert h.run().outcome == "completed"
    for sent, answered in ((MotorCommand, SensorReading), (Stimulation, SpikeBatch)):
        tx, rx = _stamps(h.record, sent, "tx"), _stamps(h.record, answered, "rx")
        assert len(rx) == 30
        assert all(tx[k] <= rx[k] for k in rx), sent.__name__


def test_a_realtime_step_that_starts_late_is_recorded_as_such(tmp_path, bus_overrides, monkeypatch):
    # Step 5's put holds the hub's thread past step 6's start (a 10 ms period).
    from hub.link import HubLink

    put = HubLink.send

    def put_held_at_step_5(self, role, raw):
        put(self, role, raw)
        if role == "culture" and Stimulation.decode(raw).step == 5:
            time.sleep(0.016)

    monkeypatch.setattr(HubLink, "send", put_held_at_step_5)
    with harness(tmp_path, bus_overrides, "loop.mode=realtime", "experiment.duration_s=0.2") as h:
        assert h.run().outcome == "completed"
    late_starts = [e.payload for e in h.record.events if e.key == "late_start"]
    assert [e["step"] for e in late_starts][:1] == [6]
    assert late_starts[0]["by_ms"] > 2.5  # more than a quarter period
    assert h.record.manifest["timing"]["late_steps"] >= len(late_starts)


def test_a_hub_made_from_a_config_not_resolved_records_it_resolved(tmp_path, bus_overrides):
    """Whoever makes the hub, its manifest holds the config as each endpoint's kind
    resolves it (the culture's and the world's contents, not their files): a recorded run
    is self-contained. Here the hub's address is taken, so the run ends as soon as it
    begins, its manifest written."""
    cfg = load_config(None, [*bus_overrides, "culture.params.noise.sd=2.0"])
    assert not isinstance(cfg.culture.params.get("config"), dict)  # not resolved yet
    taken = open_session(cfg.bus, listener=True)
    try:
        with pytest.raises(BusError):
            Hub(cfg, run_dir=tmp_path).run()
    finally:
        taken.close()
    manifest = read_manifest(tmp_path)
    assert manifest["outcome"] == "fault" and "cannot listen" in manifest["reason"]
    assert manifest["config"] == cfg.resolved().to_dict()
    assert manifest["config"]["culture"]["params"]["config"]["noise"]["sd"] == 2.0
