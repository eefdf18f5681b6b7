"""Benchmark of the wire layer (``hub/protocol.py``): CPU microseconds per call.

Per loop message type, at the sizes a closed loop sends (SpikeBatch with 0-300 spikes,
Stimulation empty and with 7 pulses, SensorReading with 7 ranges, MotorCommand), times
construction from values already in their wire types, ``encode()`` and ``decode()``.
Figures are CPU time (``time.process_time``) per call: each is the median over
``--repeat`` rounds of enough calls to last about ``--round-s`` seconds, so another
process on the machine changes them little.

Then the sealing and framing of ``hub/wire.py`` (no bus: the publisher only keeps what
it is given): the CPU cost per message that :class:`Outbox.put` and :class:`Inbox.feed`
add to a 300-spike SpikeBatch (sealed: tag made and checked; open: no key), and the
throughput of a 1 MB payload split into frames and reassembled (MB/s, 1 MB = 1e6 bytes).

Then the stimulation limits of ``hub/limits.py`` as the hub and a culture's endpoint apply
them each step: a stimulation of 28 pulses on 28 of 1,024 channels, checked and counted,
in a stream of steps (10 ms) at the simulated culture's ``max_pulse_hz`` (200), the rate
window full but for the stream's first second.

Last, an endpoint's whole handling of one input (:meth:`hub.endpoint.Endpoint.handle`:
unseal, decode, check, step; then encode and seal its reply), for the trivial endpoints of
``bench/loop.py`` (``tests/endpoints.py``): *warm*, inputs back to back, and *cold*, each
input after reading a buffer larger than the CPU's last-level cache (:data:`FLUSH_BYTES`),
so that the interpreter, the message classes and the endpoint start from memory. Medians
of the wall time per input. In the trivial lockstep loop, with the other processes and the
kernel's networking running between any two inputs, the same handling took about three
times its warm figure (docs/measurements/loop-cost.md,
"Where the trivial loop's pace is set").

    .venv/bin/python bench/protocol.py             # about 8 s
    .venv/bin/python bench/protocol.py --repeat 3  # quicker

The last line printed is one JSON object (keys ``<op>_us_<message>_<size>``, and
``wire_<op>_us_<message>_<sealed|open>``, ``wire_<op>_mb_per_s_1mb_<sealed|open>``,
``limits_us_stimulation_28``, ``handle_us_<body|culture>_<warm|cold>``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from hub.limits import StimulationLimits  # noqa: E402
from hub.protocol import (  # noqa: E402
    MotorCommand,
    RunStart,
    SensorReading,
    SpikeBatch,
    StepWindow,
    Stimulation,
)
from hub.wire import Inbox, Outbox, new_key  # noqa: E402
from sim_network.endpoint import MAX_PULSE_HZ  # noqa: E402
from tests.endpoints import EchoBody, EchoCulture  # noqa: E402

# Larger than the last-level cache of the machines this runs on (16-32 MB per EPYC CCX).
FLUSH_BYTES = 64 << 20


def per_call_us(fn, repeat: int, round_s: float) -> float:
    """Median CPU microseconds of one ``fn()`` call over ``repeat`` rounds."""
    fn()  # once outside the rounds: what happens once a process (a kernel compiled)
    number, spent = 1, 0.0
    while spent < round_s / 10:  # calibrate: a round lasts about round_s
        number *= 2
        start = time.process_time()
        for _ in range(number):
            fn()
        spent = time.process_time() - start
    number = max(1, int(number * round_s / max(spent, 1e-9)))
    rounds = []
    for _ in range(repeat):
        start = time.process_time()
        for _ in range(number):
            fn()
        rounds.append((time.process_time() - start) / number * 1e6)
    return statistics.median(rounds)


# Step 5 of a run with a 10 ms period: the window every loop message of the bench carries.
WINDOW = StepWindow.of("0" * 32, 5, 0.01)


def spike_batch_fields(n: int, rng: np.random.Generator) -> dict:
    return dict(
        **WINDOW.stamp,
        channel=rng.integers(0, 1024, n).astype(np.uint32),
        t_ms=np.sort(rng.uniform(0.0, 10.0, n)).astype(np.float32),
    )


def stimulation_fields(n: int, rng: np.random.Generator) -> dict:
    if n == 0:
        return dict(WINDOW.stamp)
    return dict(
        **WINDOW.stamp,
        channel=np.arange(n, dtype=np.uint32),
        amplitude_ua=rng.uniform(10, 50, n).astype(np.float32),
        width_ms=np.full(n, 0.2, dtype=np.float32),
        onset_ms=rng.uniform(0, 9.9, n).astype(np.float32),
    )


def sensor_reading_fields(n: int, rng: np.random.Generator) -> dict:
    return dict(
        step=5,
        run=WINDOW.run,
        t_s=WINDOW.t1_s,
        ranges_m=rng.uniform(0.0, 0.3, n).astype(np.float32),
        pose=np.array([0.1, -0.2, 1.5]),
        contact=False,
    )


def motor_command_fields(n: int, rng: np.random.Generator) -> dict:
    return dict(**WINDOW.stamp, left_mps=0.1, right_mps=-0.05, v_mps=0.025, omega_rad_s=-2.8)


CASES = [  # (message type, a maker of its fields, size)
    (SpikeBatch, spike_batch_fields, 0),
    (SpikeBatch, spike_batch_fields, 3),
    (SpikeBatch, spike_batch_fields, 30),
    (SpikeBatch, spike_batch_fields, 300),
    (Stimulation, stimulation_fields, 0),
    (Stimulation, stimulation_fields, 7),
    (SensorReading, sensor_reading_fields, 7),
    (MotorCommand, motor_command_fields, 0),
]


class KeepLast:
    """A publisher that keeps the last put (no bus: the figures are the wire layer's)."""

    def __init__(self):
        self.puts: list = []

    def put(self, payload, *, attachment=None):
        self.puts.append((payload, attachment))
        if len(self.puts) > 64:
            del self.puts[:-64]


def wire_cases(raw_small: bytes, repeat: int, round_s: float) -> dict:
    """CPU cost of sealing and framing: per small message (us) and for 1 MB (MB/s)."""
    result = {}
    big = np.random.default_rng(2).bytes(1_000_000)
    for sealed in (True, False):
        key = new_key() if sealed else None
        label = "sealed" if sealed else "open"
        pub = KeepLast()
        out, inbox = Outbox(pub, key), Inbox(key)
        out.put(raw_small)
        small = pub.puts[-1]
        assert inbox.feed(*small) == raw_small
        put_us = per_call_us(lambda out=out: out.put(raw_small), repeat, round_s)
        feed_us = per_call_us(lambda i=inbox, m=small: i.feed(*m), repeat, round_s)
        result[f"wire_put_us_spikebatch_300_{label}"] = round(put_us, 2)
        result[f"wire_feed_us_spikebatch_300_{label}"] = round(feed_us, 2)

        pub.puts.clear()
        out.put(big)
        framed = list(pub.puts)

        def put_big(out=out, pub=pub):
            out.put(big)
            pub.puts.clear()

        def feed_big(inbox=inbox, framed=framed):
            for m in framed:
                whole = inbox.feed(*m)
            assert len(whole) == len(big)

        put_mb_s = 1e6 / per_call_us(put_big, repeat, round_s)  # 1 MB per call
        feed_mb_s = 1e6 / per_call_us(feed_big, repeat, round_s)
        result[f"wire_put_mb_per_s_1mb_{label}"] = round(put_mb_s, 1)
        result[f"wire_feed_mb_per_s_1mb_{label}"] = round(feed_mb_s, 1)
        print(
            f"wire {label:<6} spikebatch_300 ({len(raw_small)} bytes): put +{put_us:5.2f} us, "
            f"feed +{feed_us:5.2f} us; 1 MB in {len(framed)} frames: put {put_mb_s:7.1f} MB/s,"
            f" feed {feed_mb_s:7.1f} MB/s",
            flush=True,
        )
    return result


def limits_case(repeat: int, round_s: float, steps: int = 3000) -> dict:
    """CPU cost of one step's stimulation limits: 28 pulses checked and counted."""
    rng = np.random.default_rng(3)
    culture = dataclasses.replace(
        EchoCulture().describe(), max_amplitude_ua=100.0, max_width_ms=1.0,
        max_pulse_hz=MAX_PULSE_HZ,
    )  # fmt: skip
    sites = rng.choice(1024, 28, replace=False).astype(np.uint32)  # a coder's fixed sites
    stims = [
        Stimulation(
            **StepWindow.of("0" * 32, k, 0.01).stamp,
            channel=sites,
            amplitude_ua=np.full(28, 50.0, np.float32),
            width_ms=np.full(28, 0.2, np.float32),
            onset_ms=np.sort(rng.uniform(0, 9.9, 28)).astype(np.float32),
        )
        for k in range(steps)
    ]
    state = {"limits": StimulationLimits(culture), "k": 0}

    def one_step():
        k = state["k"]
        if k == steps:  # the stream starts again, with a new run's limits
            state["limits"], k = StimulationLimits(culture), 0
        limits, stim = state["limits"], stims[k]
        if limits.violation(stim) is None:
            limits.accept(stim)
        state["k"] = k + 1

    us = per_call_us(one_step, repeat, round_s)
    print(f"limits: a 28-pulse stimulation checked and counted {us:6.2f} us", flush=True)
    return {"limits_us_stimulation_28": round(us, 2)}


class _Publisher:
    """Stands in for a Zenoh publisher (the bus is not what is measured): keeps what it
    is given, or drops it."""

    def __init__(self, keep: bool):
        self.payloads: list[bytes] = []
        self.keep = keep

    def put(self, payload: bytes) -> None:
        if self.keep:
            self.payloads.append(payload)


def handle_case(n_inputs: int = 2000) -> dict:
    """Wall microseconds of an endpoint's handling of one input and its reply, warm and
    cold (the medians over ``n_inputs`` inputs each)."""
    run = "0" * 32
    flush = np.ones(FLUSH_BYTES // 8)
    result = {}
    for endpoint in (EchoBody(), EchoCulture()):
        key = new_key()
        start = RunStart(
            run=run, period_ms=10.0, n_steps=4 * n_inputs, mode="lockstep",
            start_unix_s=time.time(), deadline_ms=10.0, key=key,
        )  # fmt: skip
        assert endpoint.take_run_request(start.encode()).ok
        replies = Outbox(_Publisher(keep=False), key)
        hub = _Publisher(keep=True)  # the sealed inputs, as the hub would put them
        inputs = Outbox(hub, key)
        for k in range(1, 2 * n_inputs + 1):
            window = StepWindow.of(run, k, 0.01)
            if endpoint.role == "body":
                message = MotorCommand(**window.stamp, left_mps=0.1, right_mps=0.1)
            else:  # the trivial loop's coder: 8 pulses on channel 0
                message = Stimulation(
                    **window.stamp, channel=np.zeros(8, np.uint32),
                    amplitude_ua=np.ones(8, np.float32), width_ms=np.ones(8, np.float32),
                    onset_ms=np.zeros(8, np.float32),
                )  # fmt: skip
            inputs.put(message.encode())
        for label, payload_range in (
            ("warm", range(n_inputs)),
            ("cold", range(n_inputs, 2 * n_inputs)),
        ):
            times = []
            for i in payload_range:
                if label == "cold":
                    flush.sum()
                t0 = time.perf_counter_ns()
                replies.put(endpoint.handle(hub.payloads[i]).encode())
                times.append(time.perf_counter_ns() - t0)
            result[f"handle_us_{endpoint.role}_{label}"] = round(statistics.median(times) / 1e3, 2)
        print(
            f"an endpoint's handling of an input ({endpoint.role}, trivial): "
            f"warm {result[f'handle_us_{endpoint.role}_warm']:6.2f} us, "
            f"cold {result[f'handle_us_{endpoint.role}_cold']:6.2f} us",
            flush=True,
        )
    return result


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--repeat", type=int, default=5, help="rounds per figure (median taken)")
    p.add_argument("--round-s", type=float, default=0.05, help="CPU seconds per round")
    args = p.parse_args(argv)
    rng = np.random.default_rng(1)
    result = {}
    for cls, make, n in CASES:
        fields = make(n, rng)
        message = cls(**fields)
        raw = message.encode()
        assert cls.decode(raw) == message
        label = cls.__name__.lower() + ("" if cls is MotorCommand else f"_{n or 'empty'}")
        ops = {
            "construct": lambda cls=cls, fields=fields: cls(**fields),
            "encode": message.encode,
            "decode": lambda cls=cls, raw=raw: cls.decode(raw),
        }
        line = []
        for op, fn in ops.items():
            us = per_call_us(fn, args.repeat, args.round_s)
            result[f"{op}_us_{label}"] = round(us, 2)
            line.append(f"{op} {us:6.2f} us")
        print(f"{label:<22} ({len(raw):5d} bytes): " + ", ".join(line), flush=True)
    raw_300 = SpikeBatch(**spike_batch_fields(300, rng)).encode()
    result.update(wire_cases(raw_300, args.repeat, args.round_s))
    result.update(limits_case(args.repeat, args.round_s))
    result.update(handle_case())
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
