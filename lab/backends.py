"""The same culture on both backends: sim_network's kernels and NEST, side by side, no bus.

    python -m lab.backends --seconds 300 [--config F] [--seed 1] [--threads 1] [--evoked]

Builds the culture file's network on sim_network (``Network``) and on NEST
(``NestNetwork``, the same sampler's arrays) with the same seed, records the same span of
spontaneous activity from each (after the same warm-up) and prints the paper's figures of
both, computed by ``hub.analysis`` as ``lab.calibrate`` computes them, with their relative
difference against `BACKEND_TOLERANCE`. ``--evoked`` adds the paper's one-neuron protocol on NEST
(10 ms, 100 µA every 5 s into the regular-spiking excitatory neuron nearest the centre, as
``lab.reproduce`` chooses it) and its PSTH peak.
The two integrators differ (docs/nest.md), so the comparison is statistical, not spike for
spike. The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import time

from hub.analysis.metrics import AnalysisParams
from hub.analysis.paper import (
    CHECKED_KEYS,
    FIRST_PULSE_AFTER_MS,
    PSTH_PEAK_RANGE_MS,
    PULSE_AMPLITUDE_UA,
    PULSE_PERIOD_MS,
    PULSE_WIDTH_MS,
)
from lab.activity import analyze_culture
from lab.calibrate import record
from lab.reproduce import stimulation_targets
from settings import ConfigError
from sim_network import Network, NetworkConfig, PeriodicStimulus, load_config
from sim_network.config import DEFAULT_CULTURE_FILE
from sim_network.layout import EXCITATORY

#: The figures compared (those judged against the paper), and how far NEST's may lie
#: from sim_network's.
COMPARED_KEYS = CHECKED_KEYS
BACKEND_TOLERANCE = 0.15
BACKENDS = ("sim_network", "nest")


def build(backend: str, cfg: NetworkConfig, seed: int, threads: int = 1):
    """The culture on one backend.

    Parameters
    ----------
    backend : {"sim_network", "nest"}
    cfg : NetworkConfig
    seed : int
    threads : int
        NEST's threads (sim_network runs on one).

    Returns
    -------
    Network or NestNetwork
    """
    if backend == "sim_network":
        return Network(cfg, seed=seed)
    if backend == "nest":
        from sim_network.nest_backend import NestNetwork

        return NestNetwork(cfg, seed=seed, threads=threads)
    raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")


def spontaneous(net, seconds: float, warmup_s: float = 5.0) -> dict:
    """The paper's figures of `seconds` of spontaneous activity after a warm-up.

    Parameters
    ----------
    net : Network or NestNetwork
        Advanced in place.
    seconds, warmup_s : float

    Returns
    -------
    dict
        ``hub.analysis`` metrics, plus ``wall_s`` (simulation only) and ``x_realtime``.
    """
    record(net, warmup_s)
    t0 = net.t_ms
    wall = time.perf_counter()
    spikes = record(net, seconds)
    wall = time.perf_counter() - wall
    out = dict(analyze_culture(spikes, net.layout, t0, net.t_ms).metrics)
    out["wall_s"] = round(wall, 2)
    out["x_realtime"] = round(seconds / wall, 2)
    return out


def evoked(net, seconds: float, warmup_s: float = 5.0) -> dict:
    """The paper's one-neuron protocol: its PSTH peak and whether it lies in 30-100 ms.

    Parameters
    ----------
    net : Network or NestNetwork
        Advanced in place.
    seconds : float
        Stimulated span (one pulse every 5 s from 1 s on).
    warmup_s : float

    Returns
    -------
    dict
        ``psth_peak_ms``, ``psth_peak_hz``, ``psth_baseline_hz`` (5 ms bins, spikes/s per
        neuron; the baseline from 200 ms after the pulse on), ``stim_neuron``, ``n_pulses``
        and ``psth_peak_in_range``.
    """
    record(net, warmup_s)
    t0 = net.t_ms
    (target,) = stimulation_targets(net.layout, EXCITATORY, 1, net.chattering_like)
    count = int(seconds // (PULSE_PERIOD_MS / 1e3))
    stim = PeriodicStimulus(
        (target,),
        PULSE_AMPLITUDE_UA,
        PULSE_WIDTH_MS,
        PULSE_PERIOD_MS,
        t0 + FIRST_PULSE_AFTER_MS,
        count,
    )
    spikes = record(net, seconds, stim=stim)
    params = AnalysisParams(psth_min_latency_ms=PULSE_WIDTH_MS)  # not the pulse itself
    res = analyze_culture(spikes, net.layout, t0, net.t_ms, stim.onsets_ms(), params)
    rate = res.psth.rate_hz
    peak = res.metrics.get("psth_peak_ms")
    lo, hi = PSTH_PEAK_RANGE_MS
    return {
        "stim_neuron": target,
        "n_pulses": count,
        "psth_peak_ms": peak,
        "psth_peak_hz": float(rate.max()),
        "psth_baseline_hz": float(rate[res.psth.edges_ms[:-1] >= 200.0].mean()),
        "psth_peak_in_range": peak is not None and lo <= peak <= hi,
    }


def relative_difference(nest_value, sim_value) -> float:
    """NEST's figure relative to sim_network's: ``nest / sim - 1``.

    Parameters
    ----------
    nest_value, sim_value : float or None
        One metric of each backend; None: not computed.

    Returns
    -------
    float
        NaN when either is None or ``sim_value`` is 0.
    """
    if nest_value is None or sim_value is None or not sim_value:
        return math.nan
    return float(nest_value) / float(sim_value) - 1.0


def compare(
    cfg: NetworkConfig, seed: int = 1, seconds: float = 300.0, threads: int = 1, warmup_s=5.0
) -> dict:
    """Spontaneous figures of both backends and their relative differences.

    Parameters
    ----------
    cfg : NetworkConfig
    seed : int
    seconds, warmup_s : float
    threads : int
        NEST's threads.

    Returns
    -------
    dict
        ``sim_network`` and ``nest`` (metrics), ``difference`` (NEST / sim_network − 1 for
        each of `COMPARED_KEYS`), ``within`` (each within `BACKEND_TOLERANCE`), ``seed``,
        ``seconds``.
    """
    out = {"seed": seed, "seconds": seconds, "threads": threads}
    for backend in BACKENDS:
        net = build(backend, cfg, seed, threads)
        out[backend] = spontaneous(net, seconds, warmup_s)
        del net
    sim, nest = out["sim_network"], out["nest"]
    out["difference"] = {k: relative_difference(nest.get(k), sim.get(k)) for k in COMPARED_KEYS}
    out["within"] = {
        k: not math.isnan(d) and abs(d) <= BACKEND_TOLERANCE for k, d in out["difference"].items()
    }
    return out


def main(argv: list[str] | None = None) -> dict:
    """Command-line entry point; returns the printed figures."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument(
        "--config",
        default=str(DEFAULT_CULTURE_FILE),
        help="culture file (default: configs/culture_1024.toml, the default culture)",
    )
    ap.add_argument("--seconds", type=float, default=300.0)
    ap.add_argument("--warmup", type=float, default=5.0, help="seconds discarded first")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--threads", type=int, default=1, help="NEST's threads")
    ap.add_argument("--set", action="append", default=[], help="dotted.key=toml_value")
    ap.add_argument("--evoked", action="store_true", help="also the evoked protocol on NEST")
    ap.add_argument("--evoked-seconds", type=float, default=150.0)
    args = ap.parse_args(argv)
    cfg = load_config(args.config, args.set)
    out = compare(cfg, args.seed, args.seconds, args.threads, args.warmup)
    print(f"{args.seconds:g} s spontaneous, seed {args.seed}, NEST threads {args.threads}")
    print(f"{'figure':>22}  {'sim_network':>11}  {'nest':>9}  difference")
    for key in (*COMPARED_KEYS, "mfr_sd_hz", "nb_duration_sd_ms", "n_network_bursts"):
        sim, nest = out["sim_network"].get(key), out["nest"].get(key)
        diff = relative_difference(nest, sim)
        mark = "" if key not in COMPARED_KEYS else (" ok" if out["within"][key] else " OUTSIDE")
        print(f"{key:>22}  {_fmt(sim):>11}  {_fmt(nest):>9}  {100 * diff:+6.1f} %{mark}")
    for backend in BACKENDS:
        print(f"{backend:>22}: {out[backend]['x_realtime']}x real time")
    if args.evoked:
        net = build("nest", cfg, args.seed, args.threads)
        out["nest_evoked"] = evoked(net, args.evoked_seconds, args.warmup)
        ev = out["nest_evoked"]
        print(
            f"NEST evoked ({ev['n_pulses']} pulses into neuron {ev['stim_neuron']}): PSTH peak "
            f"{ev['psth_peak_ms']} ms ({ev['psth_peak_hz']:.1f} vs baseline "
            f"{ev['psth_baseline_hz']:.1f} spikes/s per neuron), in 30-100 ms: "
            f"{ev['psth_peak_in_range']}"
        )
    print(json.dumps(out))
    return out


def _fmt(value) -> str:
    return "-" if value is None else f"{value:.3f}"


if __name__ == "__main__":
    try:
        main()
    except ConfigError as exc:
        raise SystemExit(f"backends: config error: {exc}") from None
