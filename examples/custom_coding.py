"""A coding scheme of your own, written in the script that runs it.

A scheme is a factory: called once with a SchemeContext (both endpoints' descriptions and
the scheme's params), it returns the per-step coder. This one stimulates the site of the
nearest obstacle's sensor only, harder the nearer it is.

    python examples/custom_coding.py
"""

import sys
from pathlib import Path

import numpy as np

from hub.coding import stimulation_sites
from hub.protocol import Stimulation
from neuvision import Experiment

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def nearest_sensor(ctx):
    """One pulse train on the sites of the sensor that sees the nearest obstacle."""
    ctx.check_params({"amplitude_ua", "width_ms"})
    amplitude_ua = ctx.param("amplitude_ua", 80.0, gt=0, le=150)
    width_ms = ctx.param("width_ms", 1.0, gt=0)
    sites = stimulation_sites(ctx)
    max_range_m = float(ctx.body.max_range_m)

    def code(sensors, window):
        s = int(np.argmin(sensors.ranges_m))
        if sensors.ranges_m[s] >= max_range_m:
            return Stimulation.none(window)  # nothing in sight: no pulse
        channel = sites[s]
        nearness = 1.0 - sensors.ranges_m[s] / max_range_m
        return Stimulation(
            **window.stamp,
            channel=channel,
            amplitude_ua=np.full(channel.size, amplitude_ua * nearness, np.float32),
            width_ms=np.full(channel.size, width_ms, np.float32),
            onset_ms=np.zeros(channel.size, np.float32),
        )

    return code


def main(duration_s: float = 20.0, runs_dir: str = "runs"):
    exp = Experiment(CONFIGS / "closed_loop.toml", {"experiment.duration_s": duration_s})
    exp.use_coding(nearest_sensor, amplitude_ua=100.0)
    run = exp.run(runs_dir=runs_dir)
    pulses = run.stimulation
    print(f"{run}: {pulses['t_ms'].size} pulses on {np.unique(pulses['channel']).size} channels")
    return run


if __name__ == "__main__":
    main(*(float(a) for a in sys.argv[1:2]))
