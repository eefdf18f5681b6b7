"""Benchmark of the MEA adapter's LSL driver: real pylsl, kept on loopback (lsl_loopback.cfg).

An instrument made here pushes Poisson spikes on an LSL outlet as they happen (60
electrodes, ``--rate-hz`` in all) and a stimulator made here reads the endpoint's marker
outlet; the endpoint is served on a real Zenoh session and stepped by a test hub
(:class:`hub.conformance.FakeHub`) at a 10 ms period, one pulse every 100 ms per site on 8
sites. Reported: spikes pushed and answered (in their window, late), how long a spike waits
from being read to leaving in a SpikeBatch (spike_to_batch), a batch's arrival at the hub
after its window's end, a pulse's due time to its marker sent (stim_to_trigger) and the
marker's trip to the stimulator, and the clock as fitted (offset, drift, LSL's correction).

    python bench/mea_lsl.py                 # 20 s
    python bench/mea_lsl.py --seconds 60

The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
os.environ.setdefault("LSLAPICFG", str(ROOT / "adapters" / "mea" / "lsl_loopback.cfg"))

import numpy as np  # noqa: E402
import pylsl  # noqa: E402

from adapters.mea.endpoint import MeaEndpoint  # noqa: E402
from adapters.mea.layout import ElectrodeLayout  # noqa: E402
from adapters.mea.lsl import LslDriver  # noqa: E402
from adapters.mea.safety import PulseLimits  # noqa: E402
from bench.host import StealMeter  # noqa: E402
from hub.conformance import FakeHub  # noqa: E402
from hub.protocol import Stimulation  # noqa: E402

PERIOD_MS = 10.0
SITES = [20, 21, 28, 29, 36, 37, 44, 45]


def pct(values, q) -> float | None:
    return round(float(np.percentile(values, q)), 3) if len(values) else None


def main(seconds: float, rate_hz: float, seed: int = 1) -> dict:
    layout = ElectrodeLayout.mcs60()
    tag = secrets.token_hex(4)
    spikes_name, stim_name = f"nv-bench-spikes-{tag}", f"nv-bench-stim-{tag}"
    info = pylsl.StreamInfo(spikes_name, "Spikes", 1, 0, "string", spikes_name)
    outlet = pylsl.StreamOutlet(info)
    stop = threading.Event()
    pushed = [0]

    def instrument():  # Poisson spikes, each pushed when it happens, stamped then
        rng = np.random.default_rng(seed)
        while not stop.is_set():
            time.sleep(rng.exponential(1.0 / rate_hz))
            outlet.push_sample([layout.names[rng.integers(layout.n)]], pylsl.local_clock())
            pushed[0] += 1

    driver = LslDriver(layout, spikes_name, stim_outlet=stim_name, stim_wait_s=10.0)
    endpoint = MeaEndpoint(driver, PulseLimits(), reply_margin_ms=1.0)
    hub = FakeHub(endpoint, input_timeout_s=1.0)
    found = pylsl.resolve_bypred(f"name='{stim_name}'", 1, 10.0)
    marker_inlet = pylsl.StreamInlet(found[0])
    marker_inlet.open_stream(10.0)
    transit_ms: list[float] = []

    def stimulator():
        while not stop.is_set():
            sample, t = marker_inlet.pull_sample(0.1)
            if sample is not None and json.loads(sample[0])["kind"] == "pulse":
                transit_ms.append((pylsl.local_clock() - t) * 1e3)

    threads = [threading.Thread(target=f, daemon=True) for f in (instrument, stimulator)]
    for t in threads:
        t.start()
    n = int(seconds * 1e3 / PERIOD_MS)
    assert hub.start(mode="realtime", n_steps=n).ok
    after_end_ms, in_window, late = [], 0, 0
    origin = time.monotonic()
    for k in range(n):
        w = hub.window(k)
        if k % 10 == 0:  # one pulse every 100 ms on each site
            each = len(SITES)
            stim = Stimulation(**w.stamp, channel=SITES, amplitude_ua=[50.0] * each,
                               width_ms=[0.4] * each, onset_ms=[5.0] * each)  # fmt: skip
        else:
            stim = Stimulation(**w.stamp)
        hub.send(stim)
        batch = hub.reply()
        after_end_ms.append((time.monotonic() - origin - w.t1_s) * 1e3)
        in_window += batch.channel.size
        late += 0 if batch.late_channel is None else batch.late_channel.size
    device = hub.counters()["device"]
    stop.set()
    hub.end()
    hub.close()
    for t in threads:
        t.join(2.0)
    return {
        "seconds": seconds,
        "period_ms": PERIOD_MS,
        "spikes_pushed": pushed[0],
        "spikes_in_window": int(in_window),
        "spikes_late": int(late),
        "spike_to_batch_ms_p50": device.get("spike_to_batch_ms_p50"),
        "spike_to_batch_ms_p99": device.get("spike_to_batch_ms_p99"),
        "batch_after_window_end_ms_p50": pct(after_end_ms, 50),
        "batch_after_window_end_ms_p99": pct(after_end_ms, 99),
        "stim_to_trigger_ms_p50": device.get("stim_to_trigger_ms_p50"),
        "stim_to_trigger_ms_p99": device.get("stim_to_trigger_ms_p99"),
        "marker_transit_ms_p50": pct(transit_ms, 50),
        "marker_transit_ms_p99": pct(transit_ms, 99),
        "pulses_sent": device.get("pulses"),
        "pulses_refused": device.get("pulses_refused"),
        "clock_offset_s": device.get("clock_offset_s"),
        "clock_offset_latest_s": device.get("clock_offset_latest_s"),
        "clock_drift_ppm": device.get("clock_drift_ppm"),
        "lsl_time_correction_s": device.get("lsl_time_correction_s"),
    }


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--rate-hz", type=float, default=1000.0, help="spikes per second, all")
    args = parser.parse_args()
    with StealMeter() as steal:
        out = main(args.seconds, args.rate_hz)
    out["steal_share"] = round(steal.share, 4)  # realtime figures: the host's steal beside them
    for key, value in out.items():
        print(f"{key:32s} {value}")
    print(json.dumps(out))
