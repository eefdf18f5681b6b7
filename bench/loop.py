"""Benchmark of the hub's loop: hub + two trivial endpoints in separate processes, loopback.

Measures the bare Zenoh round trip between two processes (the floor under every step),
lockstep steps per second, and for realtime mode at 1 ms and 10 ms
periods the lateness of step starts (median, p99) and the share of late steps.

Lockstep runs twice: with the hub on a CPU of its own and the endpoints on the others
(``loop.cpus``, ``body.cpus``, ``culture.cpus``; docs/architecture.md, "CPU placement") — the
``lockstep_steps_per_s`` figure — and with every process wherever the OS puts it, the
default (``lockstep_os_placement_steps_per_s``). Realtime runs use the default.
Recording is on, as in a real run. The endpoints are the trivial test fixtures
of ``tests/endpoints.py`` (they do no work), so the figures are the loop's own.

Large messages, two figures:

- the round trip of a 1 MB payload sealed and framed by ``hub/wire.py`` (router and a
  client in this process, the far client in another, low-latency transport as in a run):
  the far end reassembles it, checks its tag and sends it back the same way, as an
  endpoint would a 1 MB SpikeBatch (median ms; MB/s = 2 MB moved per median round trip);
- lockstep with the test culture's SpikeBatch padded to 1 MB (:class:`MegabyteCulture`),
  over the default transport and with ``bus.low_latency = false``. While the hub and the
  endpoints do not send through ``Outbox``/``Inbox``, the first is "not carried" (the
  culture's link drops at step 0) and only the second is measured.

    python bench/loop.py            # 10,000 steps per figure (about 2 minutes)
    python bench/loop.py --steps 2000
    python bench/loop.py --realtime-priority 0     # realtime under the ordinary scheduler
    python bench/loop.py --only-large --large-steps 200   # the 1 MB figures alone

The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import queue
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))

from bench.host import StealMeter, child_popen, interrupt_on_sigterm  # noqa: E402
from hub.bus import LOOP_PUBLISH, free_tcp_port, open_session, payload_bytes  # noqa: E402
from hub.config import BusSection, load_config  # noqa: E402
from hub.launch import start_local_endpoints, stop_local_endpoints  # noqa: E402
from hub.loop import Hub  # noqa: E402
from hub.wire import Inbox, Outbox  # noqa: E402
from tests.endpoints import N_CHANNELS, EchoCulture  # noqa: E402

LARGE_BYTES = 1_000_000

TRIVIAL = [
    'body.kind="tests.endpoints:EchoBody"',
    'culture.kind="tests.endpoints:EchoCulture"',
    'coding.scheme="tests.endpoints:code_step_count"',
    'decoding.scheme="tests.endpoints:decode_step"',
]


def run_once(mode: str, period_ms: float, steps: int, *extra: str) -> dict:
    overrides = [
        *TRIVIAL,
        *extra,
        f'bus.session="bench-{os.getpid()}-{mode}-{period_ms:g}"',
        f'bus.listen=["tcp/127.0.0.1:{free_tcp_port()}"]',
        f'loop.mode="{mode}"',
        f"loop.period_ms={period_ms}",
        f"experiment.duration_s={steps * period_ms / 1e3}",
    ]
    cfg = load_config(None, overrides)
    with tempfile.TemporaryDirectory() as tmp:
        procs = start_local_endpoints(None, overrides, cfg, Path(tmp))
        try:
            result = Hub(cfg, run_dir=Path(tmp)).run()
        finally:
            stop_local_endpoints(procs)
        endpoints = json.loads((Path(tmp) / "manifest.json").read_text())["endpoints"]
    if result.outcome != "completed":
        raise SystemExit(f"{mode} {period_ms} ms run failed: {result.reason}")
    # CPU time per step of each process, all its threads: what bounds lockstep on few cores.
    n = max(result.steps, 1)
    cpu_us = {"hub": result.timing["hub_cpu_s"] / n * 1e6}
    cpu_us.update({role: e["cpu_s"] / n * 1e6 for role, e in endpoints.items()})
    return {**result.timing, "cpu_us_per_step": cpu_us}


class MegabyteCulture(EchoCulture):
    """The trivial test culture, its every SpikeBatch padded to about 1 MB of valid spikes
    (125,000 spikes of 8 bytes, over its channels and inside its step)."""

    kind = "bench_megabyte_culture"
    N_SPIKES = LARGE_BYTES // 8

    def step(self, *args):  # the contract's step arguments, whatever they are
        batch = super().step(*args)
        if batch is None:
            return None
        n = self.N_SPIKES
        span_ms = (batch.t1_s - batch.t0_s) * 1e3
        return dataclasses.replace(
            batch,
            channel=np.arange(n, dtype=np.uint32) % N_CHANNELS,
            t_ms=np.linspace(0.0, span_ms, n, endpoint=False, dtype=np.float32),
        )


def large_step(steps: int) -> dict:
    """Lockstep with the culture's SpikeBatch padded to 1 MB: the step through the loop,
    over the default (low-latency) transport and over Zenoh's other one."""
    out = {}
    for name, extra in (("", []), ("_no_lowlatency", ["bus.low_latency=false"])):
        culture = 'culture.kind="bench.loop:MegabyteCulture"'
        label = f"lockstep, 1 MB SpikeBatches{name.replace('_', ' ')}"
        try:
            t = run_once("lockstep", 10.0, steps, culture, *extra)
        except SystemExit as exc:
            print(f"{label}: not carried: {exc}")
            out[f"lockstep_1mb_spikes{name}_step_ms_median"] = None
            continue
        print(
            f"{label}, {steps} steps: {t['steps_per_s']:.0f} steps/s  "
            f"step median {t['step_ms_median']:.3f} ms  p99 {t['step_ms_p99']:.3f} ms"
        )
        out[f"lockstep_1mb_spikes{name}_steps_per_s"] = round(t["steps_per_s"], 1)
        out[f"lockstep_1mb_spikes{name}_step_ms_median"] = round(t["step_ms_median"], 3)
        out[f"lockstep_1mb_spikes{name}_step_ms_p99"] = round(t["step_ms_p99"], 3)
    return out


def placement() -> tuple[list[str], str]:
    """Config overrides that give the hub a CPU of its own and the endpoints the others
    (docs/architecture.md, "CPU placement"), and their description; none on a single CPU."""
    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if len(cpus) < 2:
        return [], "wherever the OS puts them"
    hub, rest = cpus[-1], cpus[:-1]
    overrides = [f"loop.cpus=[{hub}]"]
    overrides += [f"{role}.cpus={rest}" for role in ("body", "culture")]
    return overrides, f"hub on CPU {hub}, endpoints on CPU {','.join(map(str, rest))}"


def _bus(port: int) -> BusSection:
    return BusSection(session=f"bench-rtt-{port}", listen=(f"tcp/127.0.0.1:{port}",))


def echo(port: int) -> None:
    """The far end of :func:`zenoh_round_trip_us`: send back every message at once."""
    bus = _bus(port)
    session = open_session(bus, listener=False)
    publisher = session.declare_publisher(f"{bus.keys.root}/pong", **LOOP_PUBLISH)
    subscriber = session.declare_subscriber(  # noqa: F841
        f"{bus.keys.root}/ping", lambda sample: publisher.put(payload_bytes(sample))
    )
    token = session.liveliness().declare_token(f"{bus.keys.root}/alive/echo")  # noqa: F841
    time.sleep(120)


def framed_echo(port: int, key_hex: str) -> None:
    """The far end of :func:`framed_round_trip_ms`: reassemble, check, send back framed."""
    bus = _bus(port)
    key = bytes.fromhex(key_hex)
    session = open_session(bus, listener=False)
    outbox = Outbox(session.declare_publisher(f"{bus.keys.root}/pong", **LOOP_PUBLISH), key)
    inbox = Inbox(key)
    received: queue.SimpleQueue = queue.SimpleQueue()
    subscriber = session.declare_subscriber(  # noqa: F841
        f"{bus.keys.root}/ping", lambda s: received.put((s.payload, s.attachment))
    )
    token = session.liveliness().declare_token(f"{bus.keys.root}/alive/echo")  # noqa: F841
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        try:
            whole = inbox.feed(*received.get(timeout=1.0))
        except queue.Empty:
            continue
        if whole is not None:
            outbox.put(whole)


def framed_round_trip_ms(n: int = 50) -> tuple[float, float]:
    """Median round trip (ms) of a 1 MB sealed, framed payload between this process (the
    router, and a client session as the hub's side) and a client in another process;
    and 2 MB moved per median round trip, in MB/s."""
    from hub.wire import new_key

    port = free_tcp_port()
    bus = _bus(port)
    key = new_key()
    router = open_session(bus, listener=True)
    session = open_session(bus, listener=False)
    received: queue.SimpleQueue = queue.SimpleQueue()
    alive = threading.Event()
    declared = [  # noqa: F841
        session.declare_subscriber(
            f"{bus.keys.root}/pong", lambda s: received.put((s.payload, s.attachment))
        ),
        session.liveliness().declare_subscriber(
            f"{bus.keys.root}/alive/echo", lambda s: alive.set(), history=True
        ),
    ]
    outbox = Outbox(session.declare_publisher(f"{bus.keys.root}/ping", **LOOP_PUBLISH), key)
    inbox = Inbox(key)
    payload = np.random.default_rng(0).bytes(LARGE_BYTES)
    cmd = [sys.executable, __file__, "--framed-echo", str(port), key.hex()]
    proc = child_popen(cmd)
    try:
        if not alive.wait(30):
            raise SystemExit("the echo process did not come up")
        times = np.empty(n)
        for i in range(n):
            t0 = time.perf_counter()
            outbox.put(payload)
            whole = None
            while whole is None:
                whole = inbox.feed(*received.get(timeout=10))
            times[i] = time.perf_counter() - t0
            if whole != payload:
                raise SystemExit("the 1 MB payload came back changed")
    finally:
        proc.kill()
        proc.wait()
        session.close()
        router.close()
    median_s = float(np.median(times[min(5, n // 10) :]))
    return median_s * 1e3, 2 * LARGE_BYTES / 1e6 / median_s


def zenoh_round_trip_us(n: int = 2000) -> float:
    """Median round trip of a 100-byte message from the hub's router to a client and back,
    with the loop's bus settings, no Python work on either side: the floor under a step."""
    port = free_tcp_port()
    bus = _bus(port)
    session = open_session(bus, listener=True)
    inbox: queue.SimpleQueue = queue.SimpleQueue()
    alive = threading.Event()
    declared = [  # noqa: F841
        session.declare_subscriber(f"{bus.keys.root}/pong", lambda s: inbox.put(None)),
        session.liveliness().declare_subscriber(
            f"{bus.keys.root}/alive/echo", lambda s: alive.set(), history=True
        ),
    ]
    publisher = session.declare_publisher(f"{bus.keys.root}/ping", **LOOP_PUBLISH)
    proc = child_popen([sys.executable, __file__, "--echo", str(port)])
    try:
        if not alive.wait(30):
            raise SystemExit("the echo process did not come up")
        times = np.empty(n)
        for i in range(n):
            t0 = time.perf_counter()
            publisher.put(bytes(100))
            inbox.get(timeout=5)
            times[i] = time.perf_counter() - t0
    finally:
        proc.kill()
        proc.wait()
        session.close()
    return float(np.median(times[n // 10 :]) * 1e6)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--realtime-priority", type=int, help="loop.realtime_priority")
    parser.add_argument("--large-rounds", type=int, default=50, help="1 MB round trips")
    parser.add_argument("--large-steps", type=int, default=500, help="lockstep steps at 1 MB")
    parser.add_argument("--only-large", action="store_true", help="the 1 MB figures alone")
    parser.add_argument("--echo", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--framed-echo", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    interrupt_on_sigterm()
    if args.echo:
        return echo(args.echo)
    if args.framed_echo:
        return framed_echo(int(args.framed_echo[0]), args.framed_echo[1])
    n = args.steps

    large_ms, large_mb_s = framed_round_trip_ms(args.large_rounds)
    print(
        f"1 MB sealed+framed round trip (router+client -> client -> back, low-latency): "
        f"median {large_ms:.2f} ms, {large_mb_s:.0f} MB/s (2 MB moved per round trip)"
    )
    large = {
        "framed_1mb_round_trip_ms_median": round(large_ms, 3),
        "framed_1mb_round_trip_mb_per_s": round(large_mb_s, 1),
    }
    large.update(large_step(args.large_steps))
    if args.only_large:
        print(json.dumps(large))
        return

    rtt_us = zenoh_round_trip_us()
    print(f"bare Zenoh round trip (router -> client -> router, no work): median {rtt_us:.0f} us")

    placed, where = placement()
    out = {}
    for tag, extra in (("placed", placed), ("os", [])):
        lock = run_once("lockstep", 10.0, n, *extra)
        print(
            f"lockstep      {n} steps: {lock['steps_per_s']:8.0f} steps/s  "
            f"step median {lock['step_ms_median']:.3f} ms  p99 {lock['step_ms_p99']:.3f} ms  "
            f"({where if tag == 'placed' else 'wherever the OS puts them'}); CPU per step "
            + ", ".join(f"{k} {v:.0f} us" for k, v in lock["cpu_us_per_step"].items())
        )
        key = "lockstep_steps_per_s" if tag == "placed" else "lockstep_os_placement_steps_per_s"
        out[key] = round(lock["steps_per_s"], 1)
        # whether idle CPUs were kept from sleeping (loop.keep_cpus_awake): it moves the figures
        out["cpus_awake"] = lock["cpus_awake"]["held"]
        for who, us in lock["cpu_us_per_step"].items():
            out[f"lockstep_{tag}_cpu_us_per_step_{who}"] = round(us, 1)
        if not placed:
            break
    out["lockstep_placement"] = where
    out["zenoh_round_trip_us"] = round(rtt_us, 1)
    extra = []
    if args.realtime_priority is not None:
        extra = [f"loop.realtime_priority={args.realtime_priority}"]
    for period in (10.0, 1.0):
        with StealMeter() as steal:
            t = run_once("realtime", period, n, *extra)
        tag = f"rt{period:g}"
        sched = t["scheduling"]
        sched = f"fifo {sched['priority']}" if sched["policy"] == "fifo" else "normal"
        out["rt_scheduling"] = sched
        print(
            f"realtime {period:4g} ms ({sched}) {n} steps: "
            f"lateness median {t['lateness_ms_median']:.3f} ms"
            f"  p99 {t['lateness_ms_p99']:.3f} ms  max {t['lateness_ms_max']:.3f} ms  "
            f"late steps {t['late_steps']} ({100 * t['late_share']:.2f} %)  "
            f"CPU steal {steal.share:.1%}"
        )
        out[f"{tag}_steal_share"] = round(steal.share, 4)
        out[f"{tag}_late_share"] = round(t["late_share"], 5)
        out[f"{tag}_p99_lateness_ms"] = round(t["lateness_ms_p99"], 4)
        out[f"{tag}_median_lateness_ms"] = round(t["lateness_ms_median"], 4)
        out[f"{tag}_max_lateness_ms"] = round(t["lateness_ms_max"], 3)
    out.update(large)
    out["steps_per_figure"] = n
    out["cpus"] = os.cpu_count()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
