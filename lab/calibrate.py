"""Calibration run: simulate the culture and print the paper's activity figures.

    python -m lab.calibrate --config configs/culture_1024.toml --seconds 60 \
        --set connectivity.weight_exc_mv=[0,6] --set noise.sd=3.5 [--evoked]

Spontaneous mode prints MFR, MBR, MNBR, network-burst duration and the excitatory share of
network-burst spikes against the paper's values; `--evoked` stimulates one excitatory neuron
near the centre with the paper's 10 ms, 100 µA, 0.2 Hz pulses and prints the PSTH peak.
The figures are computed by `hub.analysis` (through `lab.activity`), the project's
one definition of bursts and network bursts. The last line is a JSON object with the figures.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from hub.analysis.metrics import AnalysisParams
from hub.analysis.paper import PAPER_TARGETS, relative_error
from lab.activity import analyze_culture
from settings import ConfigError
from sim_network.config import load_config
from sim_network.network import Network
from sim_network.records import PeriodicStimulus, Spikes


def record(
    net: Network, seconds: float, chunk_ms: float = 1000.0, stim=None, on_chunk=None
) -> Spikes:
    """Run a network for a while in chunks and collect its neuron-level spikes.

    Parameters
    ----------
    net : Network
        Advanced in place from its current time.
    seconds : float
        Simulated time.
    chunk_ms : float
        Length of each `Network.run` call.
    stim : PeriodicStimulus, optional
        Its pulses are given to the calls they start in.
    on_chunk : callable, optional
        ``on_chunk(step_ms)`` after each chunk (progress reports).

    Returns
    -------
    Spikes
        Neuron-level spikes (absolute times) of the whole time.
    """
    parts = []
    t_end = net.t_ms + seconds * 1000.0
    while net.t_ms < t_end - 1e-9:
        step = min(chunk_ms, t_end - net.t_ms)
        pulses = stim.pulses_between(net.t_ms, net.t_ms + step) if stim is not None else None
        net.run(step, pulses=pulses)
        parts.append(net.neuron_spikes)
        if on_chunk is not None:
            on_chunk(step)
    return Spikes.concat(parts)


def central_excitatory_neuron(net: Network) -> int:
    """The excitatory neuron nearest the culture centre.

    Parameters
    ----------
    net : Network

    Returns
    -------
    int
        Its index.
    """
    lay = net.layout
    d = np.hypot(lay.x_um - lay.width_um / 2, lay.y_um - lay.height_um / 2)
    d[lay.cell_type != 0] = np.inf
    return int(np.argmin(d))


def main(argv: list[str] | None = None) -> dict:
    """Command-line entry point; returns the printed figures."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--config", default=None, help="culture file (default: the calibrated culture)")
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--warmup", type=float, default=5.0, help="seconds discarded first")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--set", action="append", default=[], help="dotted.key=toml_value")
    ap.add_argument("--evoked", action="store_true")
    args = ap.parse_args(argv)
    cfg = load_config(args.config, args.set)  # the one loader: errors name the key
    net = Network(cfg, seed=args.seed)
    record(net, args.warmup)
    t0 = net.t_ms
    wall = time.perf_counter()
    stim = None
    if args.evoked:
        target = central_excitatory_neuron(net)
        count = int(args.seconds // 5.0)
        stim = PeriodicStimulus((target,), 100.0, 10.0, 5000.0, t0 + 1000.0, count)
    sp = record(net, args.seconds, stim=stim)
    wall = time.perf_counter() - wall
    stim_ms = stim.onsets_ms() if stim is not None else None
    # skip the direct response during the pulse itself when looking for the evoked peak
    params = AnalysisParams(psth_min_latency_ms=10.0)
    res = analyze_culture(sp, net.layout, t0, net.t_ms, stim_ms, params)
    out = dict(res.metrics)
    out["x_realtime"] = round(args.seconds / wall, 2)
    if stim is not None:
        rate = res.psth.rate_hz
        out["stim_neuron"] = stim.channels[0]
        out["psth_baseline_hz"] = float(rate[res.psth.edges_ms[:-1] >= 200.0].mean())
        out["psth_peak_hz"] = float(rate.max())
        print("PSTH (5 ms bins, spikes/s per neuron):", np.round(rate[:40], 1).tolist())
    for key, ref in PAPER_TARGETS.items():
        value = out[key] if out[key] is not None else float("nan")
        err = relative_error(value, ref)
        print(f"{key:>22}: {value:9.3f}   paper {ref:7.2f}   {100 * err:+5.0f} %")
    for key in (
        "mfr_exc_hz",
        "mfr_inh_hz",
        "nb_core_duration_ms",
        "nb_participation",
        "nb_exc_spike_fraction",
        "n_network_bursts",
        "psth_peak_ms",
        "x_realtime",
    ):
        if key in out:
            print(f"{key:>22}: {out[key]}")
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    try:
        main()
    except ConfigError as exc:
        raise SystemExit(f"calibrate: config error: {exc}") from None
