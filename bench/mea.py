"""Benchmark of the MEA adapter against its emulator (a process of its own, TCP on loopback).

A hybrid realtime run (emulated Intan RHX + simulated arena, configs/hybrid_mea.toml): how
long a pulse waits from its due time to its trigger being sent (stim_to_trigger), how long a
spike waits from being read off the spike port to leaving in a SpikeBatch (spike_to_batch),
and the late steps, at a 10 ms and a 20 ms period, with the host's stalls seen meanwhile
(``tests/stall_witness.py``: how many missed replies no stall explains). Spikes are
streamed in parts of their window as they come (contract v4,
``culture.params.stream_spikes_ms``, 1 ms by default);
``--stream-spikes-ms 0`` measures the same runs with one batch per window.

    python bench/mea.py                 # 20 s per period
    python bench/mea.py --seconds 60
    python bench/mea.py --stream-spikes-ms 0

The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.host import StealMeter, child_popen, child_run, end_children_on_signal  # noqa: E402
from hub.bus import free_tcp_port  # noqa: E402
from hub.record import read_run  # noqa: E402
from tests.stall_witness import StallWitness  # noqa: E402


def hybrid(seconds: float, period_ms: float, stream_spikes_ms: float | None = None) -> dict:
    """One hybrid run against an emulator child; its manifest's figures."""
    ports = free_tcp_port(), free_tcp_port()
    emu = child_popen(
        [sys.executable, "-m", "hub.cli", "emulate", "intan", "--command-port", str(ports[0]),
         "--spike-port", str(ports[1])],
        cwd=ROOT, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    emu.stderr.readline()  # listening
    try:
        with tempfile.TemporaryDirectory() as tmp:
            cmd = [sys.executable, "-m", "hub.cli", "run", "configs/hybrid_mea.toml", "--quiet"]
            cmd += ["--duration-s", str(seconds), "--runs-dir", tmp, "--session", "bench-mea"]
            for item in (f"culture.params.command_port={ports[0]}",
                         f"culture.params.spike_port={ports[1]}", f"loop.period_ms={period_ms}",
                         f"loop.deadline_ms={period_ms * 1.8}"):  # fmt: skip
                cmd += ["--set", item]
            if stream_spikes_ms is not None:
                cmd += ["--set", f"culture.params.stream_spikes_ms={stream_spikes_ms}"]
            with StealMeter() as steal, StallWitness() as witness:
                done = child_run(cmd, cwd=ROOT)
            if done.returncode != 0:
                raise SystemExit(f"hybrid run failed:\n{done.stderr[-2000:]}")
            (run_dir,) = Path(tmp).iterdir()
            m = json.loads((run_dir / "manifest.json").read_text())
            stalls = witness.figures(read_run(run_dir))
    finally:
        emu.terminate()
        emu.wait(timeout=10)
    t, device = m["timing"], m["endpoints"]["culture"]["device"]
    print(
        f"hybrid {seconds:g} s at {period_ms:g} ms: {t['steps']} steps, late {t['late_steps']}, "
        f"start lateness median {t['lateness_ms_median']:.2f} ms p99 {t['lateness_ms_p99']:.2f}"
        f" ms; stim→trigger p50 {device.get('stim_to_trigger_ms_p50', float('nan')):.3f} ms p99 "
        f"{device.get('stim_to_trigger_ms_p99', float('nan')):.3f} ms ({device['pulses']} pulses)"
        f"; spike→batch p50 {device.get('spike_to_batch_ms_p50', float('nan')):.2f} ms p99 "
        f"{device.get('spike_to_batch_ms_p99', float('nan')):.2f} ms; late spikes "
        f"{device['late_spikes']}; "
        f"{device.get('spike_parts_sent', 0) / max(t['steps'], 1):.2f} parts a step; hub CPU "
        f"{t['hub_cpu_s'] / max(t['steps'], 1) * 1e6:.0f} µs a step; clock drift "
        f"{device['clock_drift_ppm']:.1f} ppm; CPU steal {steal.share:.1%}; "
        f"{witness.summary()}, replies missed {stalls['missed_replies']}, of which no stall "
        f"explains {stalls['missed_replies_unexplained']}"
    )
    return {"timing": t, "device": device, "steal": steal.share, "stalls": stalls}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="length of each run (s)")
    parser.add_argument(
        "--stream-spikes-ms", type=float, default=None,
        help="culture.params.stream_spikes_ms for the runs (default: the config's; 0: no parts)",
    )  # fmt: skip
    args = parser.parse_args()
    end_children_on_signal()
    out = {}
    for period_ms in (10.0, 20.0):
        r = hybrid(args.seconds, period_ms, args.stream_spikes_ms)
        tag = f"rt{period_ms:g}"
        d = r["device"]
        out[f"{tag}_stim_to_trigger_ms_p99"] = round(d.get("stim_to_trigger_ms_p99", -1), 3)
        # -1: none measured (no spike reached a batch from the spike port)
        out[f"{tag}_spike_to_batch_ms_p99"] = round(d.get("spike_to_batch_ms_p99", -1), 3)
        out[f"{tag}_hybrid_late_steps"] = r["timing"]["late_steps"]
        out[f"{tag}_steal_share"] = round(r["steal"], 4)
        out.update({f"{tag}_{k}": v for k, v in r["stalls"].items()})
        out[f"{tag}_spike_parts_per_step"] = round(
            d.get("spike_parts_sent", 0) / max(r["timing"]["steps"], 1), 3
        )
        out[f"{tag}_hub_cpu_us_per_step"] = round(
            r["timing"]["hub_cpu_s"] / max(r["timing"]["steps"], 1) * 1e6, 1
        )
    # the keys: the 10 ms run
    out["stim_to_trigger_ms_p99"] = out["rt10_stim_to_trigger_ms_p99"]
    out["spike_to_batch_ms_p99"] = out["rt10_spike_to_batch_ms_p99"]
    out["hybrid_late_steps"] = out["rt10_hybrid_late_steps"]
    out["seconds"] = args.seconds
    print(json.dumps(out))


if __name__ == "__main__":
    main()
