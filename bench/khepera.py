"""Benchmark of the Khepera adapter against its emulator (a separate process, a real pty).

1. The serial cycle: one motor write (``D``) and one proximity read (``N``) through the
   adapter's link, at 9600 and at 115200 baud, against the byte-time bound of each baud
   (the bytes of both exchanges at 11 bits a byte: 8N2); and a Khepera III's at 115200
   (its dialect: typed integers, 12 fields in ``N``; 8N1, 10 bits a byte).
2. A hybrid realtime run (emulated Khepera + simulated culture, configs/hybrid_khepera.toml)
   at 9600 baud and a 50 ms period: late steps, and the age of the readings the steps got;
   the host's stalls seen meanwhile (``tests/stall_witness.py``).

    python bench/khepera.py                # 200 cycles per baud, a 20 s hybrid run
    python bench/khepera.py --seconds 60

The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from adapters.khepera.link import SerialLink, byte_time_s, open_port  # noqa: E402
from adapters.khepera.protocol import command  # noqa: E402
from bench.host import StealMeter, child_popen, child_run, end_children_on_signal  # noqa: E402
from devices.khepera import MODELS  # noqa: E402
from hub.record import read_run  # noqa: E402
from tests.stall_witness import StallWitness  # noqa: E402

EMULATE = [sys.executable, "-m", "hub.cli", "emulate", "khepera"]


#: a Khepera III's emulator needs an IR table (none is published): one for the benchmark only
K3_TABLE = "distance_m,value\n0.02,1000\n0.05,500\n0.1,180\n0.2,30\n"


def emulator(baud: int, dialect: str = "khepera2", ir_table: str | None = None):
    """A ``neuvision emulate khepera`` child and its device path."""
    extra = ["--dialect", dialect] + (["--ir-table", ir_table] if ir_table else [])
    proc = child_popen(
        [*EMULATE, "--baud", str(baud), *extra],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    return proc, proc.stdout.readline().strip()


def serial_cycle(baud: int, cycles: int, dialect: str = "khepera2") -> dict:
    """Median time of one D + N exchange, and its byte-time bound."""
    stop_bits = MODELS[dialect].stop_bits
    if MODELS[dialect].ir_table is not None:
        proc, path = emulator(baud, dialect)
    else:  # the emulator reads the table before it prints its path
        with tempfile.NamedTemporaryFile("w", suffix=".csv") as table:
            table.write(K3_TABLE)
            table.flush()
            proc, path = emulator(baud, dialect, table.name)
    try:
        port = open_port(path, baud=baud, stop_bits=stop_bits)
        link = SerialLink(port, timeout_s=0.5, dialect=dialect)
        times_s, bound_s = [], []
        with StealMeter() as steal:
            for i in range(cycles):
                speed = (i % 20) - 10  # the speeds change every cycle: a real write
                t0 = time.perf_counter()
                link.transact("D", speed, -speed)
                n = link.transact("N")
                times_s.append(time.perf_counter() - t0)
                reply_n = 2 + len(",".join(str(v) for v in n.fields)) + 2
                d_bytes = len(command("D", speed, -speed, dialect=dialect))
                n_bytes = d_bytes + 3 + len(command("N")) + reply_n
                bound_s.append(n_bytes * byte_time_s(baud, stop_bits))
        link.close()
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    cycle_ms = statistics.median(times_s) * 1e3
    bound_ms = statistics.median(bound_s) * 1e3
    print(
        f"{MODELS[dialect].name} serial cycle at {baud} baud: median {cycle_ms:.2f} ms over "
        f"{cycles} cycles, "
        f"byte-time bound {bound_ms:.2f} ms ({cycle_ms / bound_ms - 1:+.1%}); CPU steal "
        f"{steal.share:.1%}"
    )
    return {"cycle_ms": cycle_ms, "bound_ms": bound_ms, "steal": steal.share}


def hybrid(seconds: float, baud: int, period_ms: float) -> dict:
    """A hybrid realtime run against an emulator child: its manifest's figures."""
    proc, path = emulator(baud)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            cmd = [sys.executable, "-m", "hub.cli", "run", "configs/hybrid_khepera.toml"]
            cmd += ["--quiet", "--duration-s", str(seconds), "--runs-dir", tmp]
            cmd += ["--session", "bench-khepera", "--set", f'body.params.port="{path}"']
            cmd += ["--set", f"body.params.baud={baud}", "--set", f"loop.period_ms={period_ms}"]
            with StealMeter() as steal, StallWitness() as witness:
                done = child_run(cmd, cwd=ROOT)
            if done.returncode != 0:
                raise SystemExit(f"hybrid run failed:\n{done.stderr[-2000:]}")
            (run_dir,) = Path(tmp).iterdir()
            m = json.loads((run_dir / "manifest.json").read_text())
            stalls = witness.figures(read_run(run_dir))
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    device = m["endpoints"]["body"]["device"]
    t = m["timing"]
    print(
        f"hybrid {seconds:g} s at {baud} baud, {period_ms:g} ms period: {t['steps']} steps, "
        f"late {t['late_steps']}, lateness p99 {t['lateness_ms_p99']:.2f} ms; serial cycle "
        f"p50 {device['cycle_ms_p50']:.1f} ms; reading age p50 "
        f"{device['reading_age_ms_p50']:.1f} ms, p99 {device['reading_age_ms_p99']:.1f} ms; "
        f"CPU steal {steal.share:.1%}; {witness.summary()}, replies missed "
        f"{stalls['missed_replies']}, of which no stall explains "
        f"{stalls['missed_replies_unexplained']}"
    )
    return {"late": t["late_steps"], "age_p99_ms": device["reading_age_ms_p99"],
            "steal": steal.share, "stalls": stalls}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cycles", type=int, default=200, help="serial cycles per baud")
    parser.add_argument("--seconds", type=float, default=20.0, help="hybrid run length (s)")
    args = parser.parse_args()
    end_children_on_signal()
    out = {}
    for baud in (9600, 115200):
        c = serial_cycle(baud, args.cycles)
        out[f"serial_cycle_ms_{baud}"] = round(c["cycle_ms"], 3)
        out[f"byte_time_bound_ms_{baud}"] = round(c["bound_ms"], 3)
        out[f"serial_steal_share_{baud}"] = round(c["steal"], 4)
    c = serial_cycle(115200, args.cycles, "khepera3")
    out["serial_cycle_ms_115200_khepera3"] = round(c["cycle_ms"], 3)
    out["byte_time_bound_ms_115200_khepera3"] = round(c["bound_ms"], 3)
    out["serial_steal_share_115200_khepera3"] = round(c["steal"], 4)
    h = hybrid(args.seconds, 9600, 50.0)
    out["reading_age_ms_p99"] = round(h["age_p99_ms"], 2)
    out["hybrid_late_steps"] = h["late"]
    out["hybrid_steal_share"] = round(h["steal"], 4)
    out.update({f"hybrid_{k}": v for k, v in h["stalls"].items()})
    out["hybrid_s"] = args.seconds
    print(json.dumps(out))


if __name__ == "__main__":
    main()
