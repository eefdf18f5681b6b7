"""Calibration run: simulate the culture and print the paper's activity figures.

    python -m lab.calibrate --config configs/culture_1024.toml --seconds 60 \
        --set connectivity.weight_exc_mv=[0,6] --set noise.sd=3.5 [--evoked]
    python -m lab.calibrate --seconds 300 --seeds 1-6 --jobs 2   # per seed, mean ± s.d.

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
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from hub.analysis.metrics import AnalysisParams
from hub.analysis.paper import (
    CHECKED_KEYS,
    FIRST_PULSE_AFTER_MS,
    PAPER_TARGETS,
    PULSE_AMPLITUDE_UA,
    PULSE_PERIOD_MS,
    PULSE_WIDTH_MS,
    SEED_TOLERANCE,
    relative_error,
    within,
)
from lab.activity import analyze_culture
from lab.seeds import mean_sd, parse_seeds
from settings import ConfigError
from sim_network.config import NetworkConfig, load_config
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


def spontaneous_statistics(
    cfg: NetworkConfig, seed: int, seconds: float, warmup_s: float = 5.0
) -> dict:
    """Simulate one seed's spontaneous activity through the library and analyse it.

    The same figures as ``lab.reproduce`` computes (``hub.analysis`` through
    ``lab.activity``), without the bus, the stimulation protocols or the figures.

    Parameters
    ----------
    cfg : NetworkConfig
        The culture.
    seed : int
        Network seed.
    seconds : float
        Analysed spontaneous activity (after the warm-up).
    warmup_s : float
        Discarded first.

    Returns
    -------
    dict
        ``hub.analysis.metrics`` keys, plus ``seed`` and ``wall_s`` (simulation and analysis).
    """
    wall = time.perf_counter()
    net = Network(cfg, seed=seed)
    record(net, warmup_s)
    t0 = net.t_ms
    spikes = record(net, seconds)
    out = dict(analyze_culture(spikes, net.layout, t0, net.t_ms).metrics)
    out.update(seed=seed, wall_s=time.perf_counter() - wall)
    return out


def statistics_over_seeds(
    cfg: NetworkConfig, seeds, seconds: float, warmup_s: float = 5.0, jobs: int = 1
) -> list[dict]:
    """`spontaneous_statistics` of several seeds, up to ``jobs`` processes at a time.

    Parameters
    ----------
    cfg : NetworkConfig
    seeds : iterable of int
    seconds, warmup_s : float
        As for `spontaneous_statistics`.
    jobs : int
        Processes at once (1: in this process).

    Returns
    -------
    list of dict
        One per seed, in the order given.
    """
    seeds = list(seeds)
    if jobs <= 1 or len(seeds) == 1:
        return [spontaneous_statistics(cfg, s, seconds, warmup_s) for s in seeds]
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(spontaneous_statistics, cfg, s, seconds, warmup_s) for s in seeds]
        return [f.result() for f in futures]


def seed_table(rows: list[dict], keys=CHECKED_KEYS, tolerance: float = SEED_TOLERANCE) -> str:
    """A markdown table of figures per seed against the paper, with mean ± s.d. over seeds.

    Parameters
    ----------
    rows : list of dict
        Metrics dicts with a ``seed`` key.
    keys : sequence of str
        The figures (metrics keys; those in ``PAPER_TARGETS`` get the verdict).
    tolerance : float
        Relative band of the verdict.

    Returns
    -------
    str
        A value marked ``**…**`` lies outside ``±tolerance`` of the paper.
    """
    head = "| seed | " + " | ".join(keys) + " |"
    lines = [head, "|" + "---|" * (len(keys) + 1)]
    lines.append("| paper | " + " | ".join(f"{PAPER_TARGETS.get(k, '—')}" for k in keys) + " |")
    for r in rows:
        cells = []
        for k in keys:
            v, ref = r.get(k), PAPER_TARGETS.get(k)
            if ref is None:
                cells.append("—" if v is None else f"{v:.2f}")
            elif v is None:
                cells.append("**—**")
            else:
                text = f"{v:.2f} ({100 * relative_error(v, ref):+.0f} %)"
                cells.append(text if within(v, ref, tolerance) else f"**{text}**")
        lines.append(f"| {r['seed']} | " + " | ".join(cells) + " |")
    stats = [mean_sd(r.get(k) for r in rows) for k in keys]
    lines.append(
        "| mean ± s.d. | "
        + " | ".join(
            "—" if s["mean"] is None else f"{s['mean']:.2f} ± {s['sd'] or 0.0:.2f}" for s in stats
        )
        + " |"
    )
    return "\n".join(lines)


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
    ap.add_argument(
        "--seeds", help="several seeds (e.g. 1-6): spontaneous figures per seed and over seeds"
    )
    ap.add_argument("--jobs", type=int, default=1, help="seeds simulated at once (--seeds)")
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error(f"--jobs must be >= 1, got {args.jobs}")
    cfg = load_config(args.config, args.set)  # the one loader: errors name the key
    if args.seeds:
        rows = statistics_over_seeds(
            cfg, parse_seeds(args.seeds), args.seconds, args.warmup, args.jobs
        )
        print(seed_table(rows, CHECKED_KEYS + ("mfr_sd_hz", "nb_participation")))
        out = {"per_seed": rows}
        print(json.dumps(out))
        return out
    net = Network(cfg, seed=args.seed)
    record(net, args.warmup)
    t0 = net.t_ms
    wall = time.perf_counter()
    stim = None
    if args.evoked:
        target = central_excitatory_neuron(net)
        count = int(args.seconds // (PULSE_PERIOD_MS / 1e3))
        stim = PeriodicStimulus(
            (target,), PULSE_AMPLITUDE_UA, PULSE_WIDTH_MS, PULSE_PERIOD_MS,
            t0 + FIRST_PULSE_AFTER_MS, count,
        )  # fmt: skip
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
