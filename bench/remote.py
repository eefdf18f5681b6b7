"""Remote participation: the loop across hosts, the cost of mutual TLS, rejoining.

    python bench/remote.py [--rounds 4] [--n 1000]

- ``lockstep_steps_per_s_netns``: 1 s of the paper's closed loop in lockstep with the hub,
  the culture and the arena each on a host of its own (Linux network namespaces joined by
  veth links; needs root), beside the same run on one host (``..._one_host``).
- ``rt20_late_steps_netem5``: a realtime run at 20 ms with ``tc netem`` 5 ± 2 ms on each
  link; null, with the reason, where this kernel has no netem.
- ``rt20_late_steps_delay5``: the same run (5 s) with each endpoint reaching the hub through
  a relay that delays every message 5 ± 2 ms each way (tests/delay_link.py), which needs
  no netem; ``rt20_late_steps_delay30`` with 30 ms each way (late steps expected).
- ``mtls_overhead_us``: median round trip hub → body → hub (a motor command out, a reading
  back, through the hub's router) over mutual TLS with the access policy, minus the same
  over plain TCP; ``password_overhead_us`` the same over TLS with a password per role
  (``bus.security = "password"``); the three interleaved in ``--rounds`` rounds of ``--n``
  round trips (``--only-round-trip``: these alone).
- ``rejoin_s``: a lockstep run whose body is SIGKILLed at step 50 and started again: the
  time from its liveliness vanishing to its rejoining (process start-up included).

Each figure is printed with the CPU steal share during its measurement; the last line is
one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import signal
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.host import StealMeter, child_popen, end_children_on_signal  # noqa: E402
from hub.bus import free_tcp_port, open_session  # noqa: E402
from hub.config import load_config  # noqa: E402
from hub.launch import start_local_endpoints, stop_local_endpoints  # noqa: E402
from hub.loop import Hub  # noqa: E402
from tests.delay_link import delayed_closed_loop  # noqa: E402
from tests.netns import UNAVAILABLE, closed_loop, hosts, netem_available  # noqa: E402

TRIVIAL = [
    'body.kind="tests.endpoints:EchoBody"',
    'culture.kind="tests.endpoints:EchoCulture"',
    'coding.scheme="tests.endpoints:code_step_count"',
    'decoding.scheme="tests.endpoints:decode_step"',
]


def _bus_overrides(security: str, certs: Path) -> list[str]:
    port = free_tcp_port()
    scheme = "tcp" if security == "none" else "tls"
    out = [f'bus.session="bench-{os.getpid()}"', f'bus.listen=["{scheme}/127.0.0.1:{port}"]']
    if security != "none":
        out += [f'bus.security="{security}"', f'bus.certs_dir="{certs}"']
    return out


def _echo(overrides: list[str]) -> None:
    """Child: as the body, answer every motor command with a reading on the sensors key."""
    bus = load_config(None, overrides).bus
    keys = bus.keys
    session = open_session(bus, listener=False, role="body")
    out = session.declare_publisher(keys.sensors("0"))
    sub = session.declare_subscriber(keys.motor("0"), lambda s: out.put(s.payload))
    token = session.liveliness().declare_token(keys.alive("body", "0"))
    signal.sigwait({signal.SIGTERM})
    del sub, token
    session.close()


def round_trip_us(overrides: list[str], n: int) -> float:
    """Median round trip (µs) hub → body → hub of a 100-byte message, with ``overrides``."""
    bus = load_config(None, overrides).bus
    keys = bus.keys
    hub = open_session(bus, listener=True)
    back: queue.SimpleQueue = queue.SimpleQueue()
    alive = threading.Event()
    declared = [  # noqa: F841
        hub.declare_subscriber(keys.sensors("0"), lambda s: back.put(1)),
        hub.liveliness().declare_subscriber(
            keys.alive("body", "0"), lambda s: alive.set(), history=True
        ),
    ]
    motor = hub.declare_publisher(keys.motor("0"))
    child = child_popen([sys.executable, __file__, "--echo", json.dumps(overrides)])
    try:
        if not alive.wait(30):
            raise SystemExit("the echo body did not come up")
        times = []
        for _ in range(n):
            t0 = time.perf_counter()
            motor.put(b"x" * 100)
            back.get(timeout=10)
            times.append(time.perf_counter() - t0)
    finally:
        child.terminate()
        child.wait()
        hub.close()
    return statistics.median(times[n // 10 :]) * 1e6


def rejoin_gap_s() -> float:
    """A lockstep run whose body is killed at step 50 and started again: its rejoin gap."""
    overrides = [
        *TRIVIAL,
        f'bus.session="bench-rejoin-{os.getpid()}"',
        f'bus.listen=["tcp/127.0.0.1:{free_tcp_port()}"]',
        "experiment.duration_s=2",
        "policy.rejoin_s=30",
        "loop.status_hz=50",
    ]
    cfg = load_config(None, overrides)
    with tempfile.TemporaryDirectory() as tmp:
        procs = start_local_endpoints(None, overrides, cfg, Path(tmp))

        def progress(p):  # in the loop's thread, which outlives the new body
            if p.step >= 50 and not hasattr(progress, "done"):
                progress.done = True
                os.kill(next(q.popen.pid for q in procs if q.role == "body"), signal.SIGKILL)
                alone = overrides + ['culture.launch="external"']
                procs.extend(start_local_endpoints(None, alone, load_config(None, alone), None))

        try:
            result = Hub(cfg, run_dir=Path(tmp), progress=progress).run()
        finally:
            stop_local_endpoints(procs)
        rejoins = json.loads((Path(tmp) / "manifest.json").read_text())["rejoins"]
    if result.outcome != "completed" or len(rejoins) != 1:
        raise SystemExit(f"the rejoin run failed: {result.outcome} {result.reason}")
    return rejoins[0]["gap_s"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--n", type=int, default=1000, help="round trips per round")
    parser.add_argument("--only-round-trip", action="store_true", help="the round trips alone")
    parser.add_argument("--echo", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.echo:
        return _echo(json.loads(args.echo))
    end_children_on_signal()
    out: dict = {}

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if args.only_round_trip:
            pass
        elif UNAVAILABLE:
            print(f"across hosts: not measured ({UNAVAILABLE})")
            out["lockstep_steps_per_s_netns"] = None
        else:
            with StealMeter() as steal:
                _, one = closed_loop(tmp, "one-host", None, "experiment.duration_s=5")
                with hosts(["body", "culture"]) as places:
                    _, three = closed_loop(tmp, "netns", places, "experiment.duration_s=5")
            a, b = one.timing["steps_per_s"], three.timing["steps_per_s"]
            print(
                f"lockstep closed loop, 5 s: one host {a:.0f} steps/s, three hosts "
                f"(netns + veth) {b:.0f} steps/s  (CPU steal {steal.share:.1%})"
            )
            out["lockstep_steps_per_s_one_host"] = round(a, 1)
            out["lockstep_steps_per_s_netns"] = round(b, 1)
            out["netns_steal_share"] = round(steal.share, 4)
        netem = None if args.only_round_trip else netem_available()
        if args.only_round_trip:
            pass
        elif netem:
            print(f"realtime 20 ms with netem 5 +- 2 ms: not measured ({netem})")
            out["rt20_late_steps_netem5"] = None
            out["rt20_netem5_not_measured"] = netem
        else:  # pragma: no cover - a kernel with sch_netem
            raise SystemExit("netem is available here: measure rt20_late_steps_netem5")

        if not args.only_round_trip:
            for delay_ms, jitter_ms in ((5.0, 2.0), (30.0, 0.0)):
                with StealMeter() as steal:
                    rec, _, _ = delayed_closed_loop(
                        tmp, f"delay{delay_ms:g}", delay_ms, jitter_ms, "loop.period_ms=20",
                        "experiment.duration_s=5",
                    )  # fmt: skip
                t = rec.manifest["timing"]
                rtt = t["round_trip_ms"]
                print(
                    f"realtime 20 ms, 5 s, each link delayed {delay_ms:g} +- {jitter_ms:g} ms "
                    f"(relay): {t['late_steps']} late of {t['steps']}; round trip median body "
                    f"{rtt['body']['median']:.1f} ms, culture {rtt['culture']['median']:.1f} ms "
                    f"(CPU steal {steal.share:.1%})"
                )
                out[f"rt20_late_steps_delay{delay_ms:g}"] = t["late_steps"]
                out[f"rt20_delay{delay_ms:g}_steal_share"] = round(steal.share, 4)

        from hub.certs import make_certificates, make_passwords

        certs = tmp / "certs"
        make_certificates(certs, ["hub", "body"], hub_hosts=["127.0.0.1"])
        make_passwords(certs, ["hub", "body"])
        rounds: dict[str, list[float]] = {"none": [], "mtls": [], "password": []}
        with StealMeter() as steal:
            for _ in range(args.rounds):  # interleaved: A, B, C, A, B, C, ...
                for security, got in rounds.items():
                    got.append(round_trip_us(_bus_overrides(security, certs), args.n))
        p, m, w = (statistics.median(rounds[k]) for k in ("none", "mtls", "password"))
        print(
            f"round trip hub -> body -> hub, median of {args.rounds} interleaved rounds of "
            f"{args.n}: plain TCP {p:.1f} us, mutual TLS + access policy {m:.1f} us "
            f"({m - p:+.1f} us), TLS + password + access policy {w:.1f} us ({w - p:+.1f} us)  "
            f"(rounds: { ({k: [round(x) for x in v] for k, v in rounds.items()}) }; "
            f"CPU steal {steal.share:.1%})"
        )
        out["round_trip_us_plain"] = round(p, 1)
        out["round_trip_us_mtls"] = round(m, 1)
        out["round_trip_us_password"] = round(w, 1)
        out["mtls_overhead_us"] = round(m - p, 1)
        out["password_overhead_us"] = round(w - p, 1)
        out["round_trip_steal_share"] = round(steal.share, 4)

    if args.only_round_trip:
        print(json.dumps(out))
        return
    gap = rejoin_gap_s()
    print(f"rejoin: body SIGKILLed at step 50 and started again, back in the run after {gap:.2f} s")
    out["rejoin_s"] = gap
    print(json.dumps(out))


if __name__ == "__main__":
    main()
