"""`analyze_run` turns a recorded run into metrics.json, figures and a self-contained report."""

import html
import json

import numpy as np
import pytest

from hub.analysis.spikes import AnalysisInputError
from hub.config import load_config
from hub.protocol import Description, SensorReading, SpikeBatch, Stimulation
from hub.record import Recorder, write_manifest
from lab.run_analysis import analyze_run, stimulus_onsets_ms
from tests.windows import RUN, W

PERIOD_MS = 10.0
N_CHANNELS = 20
STIM_EVERY_STEPS = 100  # one pulse a second
# every stimulus evokes, in channels 0-9 (50 %), spikes at these latencies: a network burst
# whose fullest 5 ms PSTH bin is [60, 65) ms
EVOKED_LATENCIES_MS = np.array([55.0, 60.0, 61.0, 62.0, 63.0, 64.0, 70.0, 80.0])


def _write_run(
    run_dir, n_steps=600, world="configs/worlds/paper.toml", config=None, stim_unanswered=False
):
    """A hand-made 6 s run: culture description, stimulations, spikes, body poses; with
    ``stim_unanswered``, a stimulation for the step after the last (sent pipelined, the
    run interrupted before the culture answered it)."""
    config = config or {"loop": {"period_ms": PERIOD_MS, "mode": "lockstep"}}
    if world is not None:
        config["body"] = {"kind": "sim_robot", "params": {"world": world}}
    manifest = {
        "name": "handmade",
        "seed": 7,
        "config": config,
        "steps": n_steps,
        "outcome": "completed",
        "timing": {"mode": "lockstep", "period_ms": PERIOD_MS, "steps": n_steps, "wall_s": 1.5},
    }
    write_manifest(run_dir, manifest)
    rec = Recorder(run_dir)
    ids = np.arange(100, 100 + N_CHANNELS, dtype=np.uint32)  # ids need not start at 0
    desc = Description(
        role="culture",
        id="0",
        kind="sim_network",
        channel=ids,
        x_um=(np.arange(N_CHANNELS) % 5 * 50.0).astype(np.float32),
        y_um=(np.arange(N_CHANNELS) // 5 * 50.0).astype(np.float32),
        cell_type=(np.arange(N_CHANNELS) % 5 == 4).astype(np.uint8),
    )
    rec.message("rx", "nv/s/culture/0/describe", desc.encode())
    # absolute spike times: a sparse background on every channel plus the evoked bursts
    stim_steps = np.arange(10, n_steps, STIM_EVERY_STEPS)
    times, chans = [], []
    for c in range(N_CHANNELS):
        t = np.arange(7.0 + 13 * c, n_steps * PERIOD_MS, 250.0)  # 4 Hz, never a burst
        times.append(t)
        chans.append(np.full(t.size, c))
    for k in stim_steps:
        for c in range(10):
            times.append(k * PERIOD_MS + 2.0 + EVOKED_LATENCIES_MS)  # onset_ms = 2
            chans.append(np.full(EVOKED_LATENCIES_MS.size, c))
    t_all = np.concatenate(times)
    c_all = np.concatenate(chans)
    order = np.argsort(t_all, kind="stable")
    t_all, c_all = t_all[order], c_all[order]
    for k in range(n_steps):
        if k in stim_steps:
            stim = Stimulation(
                **W(int(k)).stamp,
                channel=ids[[0, 1]],
                amplitude_ua=np.full(2, 100.0, np.float32),
                width_ms=np.full(2, 10.0, np.float32),
                onset_ms=np.full(2, 2.0, np.float32),
            )
            rec.message("tx", "nv/s/culture/0/stim", stim.encode())
        lo, hi = np.searchsorted(t_all, [k * PERIOD_MS, (k + 1) * PERIOD_MS])
        batch = SpikeBatch(
            step=k,
            run=RUN,
            t0_s=k * PERIOD_MS / 1e3,
            t1_s=(k + 1) * PERIOD_MS / 1e3,
            channel=ids[c_all[lo:hi]],
            t_ms=(t_all[lo:hi] - k * PERIOD_MS).astype(np.float32),
        )
        rec.message("rx", "nv/s/culture/0/spikes", batch.encode())
        angle = k / n_steps * 2 * np.pi
        reading = SensorReading(
            step=k,
            run=RUN,
            t_s=k * PERIOD_MS / 1e3,
            ranges_m=[0.2],
            pose=[0.3 * np.cos(angle), 0.3 * np.sin(angle), angle],
            contact=False,
        )
        rec.message("rx", "nv/s/body/0/sensors", reading.encode())
    if stim_unanswered:
        stim = Stimulation(
            **W(n_steps).stamp,
            channel=ids[[0]],
            amplitude_ua=np.full(1, 100.0, np.float32),
            width_ms=np.full(1, 10.0, np.float32),
            onset_ms=np.full(1, 2.0, np.float32),
        )
        rec.message("tx", "nv/s/culture/0/stim", stim.encode())
    rec.close()
    return stim_steps


def test_a_stimulation_of_a_step_the_run_never_finished_is_not_counted(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    stim_steps = _write_run(run_dir, n_steps=250, world=None, stim_unanswered=True)
    metrics = analyze_run(run_dir)["metrics"]
    assert metrics["duration_s"] == pytest.approx(2.5)
    assert metrics["n_stimuli"] == stim_steps.size  # not the last one, sent for step 250


@pytest.mark.slow
def test_a_recorded_run_gives_metrics_figures_and_a_report(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    stim_steps = _write_run(run_dir)
    out = analyze_run(run_dir)

    assert out["out_dir"] == run_dir / "analysis"
    metrics = json.loads((run_dir / "analysis" / "metrics.json").read_text())
    assert metrics == out["metrics"]
    assert metrics["duration_s"] == pytest.approx(6.0)
    assert metrics["n_channels"] == N_CHANNELS
    # two pulses at the same time are one stimulus
    assert metrics["n_stimuli"] == stim_steps.size
    assert metrics["n_network_bursts"] == stim_steps.size
    assert metrics["n_evoked_nb"] == stim_steps.size
    assert metrics["psth_peak_ms"] == pytest.approx(62.5)  # centre of the planted [60, 65) bin
    assert metrics["nb_duration_ms"] == pytest.approx(25.0)  # first to last evoked spike
    assert metrics["body_distance_m"] > 1.5  # a circle of radius 0.3 m

    names = {p.name for p in out["figures"]}
    for stem in ("raster", "rate", "isi", "ibi", "psth", "cats_evoked", "trajectory"):
        assert {f"{stem}.png", f"{stem}.svg"} <= names
    for p in out["figures"]:
        assert p.is_file() and p.stat().st_size > 1000
    html = out["report_path"].read_text()
    assert out["report_path"] == run_dir / "analysis" / "report.html"
    assert html.count("data:image/png;base64,") == len(names) // 2  # one image per figure
    assert "wall_s" in html and "period_ms" in html and "handmade" in html


@pytest.mark.slow  # a run and its analysis
def test_analyze_uses_the_analysis_table_the_run_recorded(tmp_path):
    # the evoked bursts take 10 of 20 channels: a network burst by the paper's 30 %, none
    # when the run's experiment asked for 60 %
    cfg = load_config(None, ["analysis.network_bursts.min_fraction=0.6"])
    assert cfg.analysis == {"network_bursts": {"min_fraction": 0.6}}
    for name, config in (("paper", None), ("strict", cfg.to_dict())):
        run_dir = tmp_path / name
        run_dir.mkdir()
        n_stimuli = _write_run(run_dir, n_steps=300, world=None, config=config).size
        metrics = analyze_run(run_dir)["metrics"]
        assert metrics["n_network_bursts"] == (n_stimuli if name == "paper" else 0)


@pytest.mark.slow
def test_a_run_without_a_known_world_has_path_metrics_and_no_trajectory(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    _write_run(run_dir, n_steps=200, world=None)
    out = analyze_run(run_dir, tmp_path / "elsewhere")
    assert (tmp_path / "elsewhere" / "metrics.json").is_file()
    assert (tmp_path / "elsewhere" / "report.html").is_file()
    assert not any(p.name.startswith("trajectory") for p in out["figures"])
    # the body's path is measured from its poses alone; arena figures need the world
    assert out["metrics"]["body_distance_m"] > 1.5
    assert out["metrics"]["body_duration_s"] == pytest.approx(1.99)
    assert "body_obstacle_entries" not in out["metrics"]


def test_a_run_without_spikes_or_steps_is_refused_with_a_clear_error(tmp_path):
    write_manifest(tmp_path, {"name": "empty", "config": {"loop": {"period_ms": 10.0}}})
    Recorder(tmp_path).close()
    with pytest.raises(AnalysisInputError, match="no spike batches and no steps"):
        analyze_run(tmp_path)


def test_a_silent_culture_still_gets_metrics_and_report(tmp_path):
    write_manifest(tmp_path, {"name": "silent", "config": {"loop": {"period_ms": 10.0}}})
    rec = Recorder(tmp_path)
    for k in range(100):
        batch = SpikeBatch(step=k, run=RUN, t0_s=k * 0.01, t1_s=(k + 1) * 0.01)
        rec.message("rx", "nv/s/culture/0/spikes", batch.encode())
    rec.close()
    out = analyze_run(tmp_path)
    assert out["metrics"]["n_spikes"] == 0 and out["metrics"]["mfr_hz"] == 0.0
    assert out["metrics"]["nb_duration_ms"] is None
    assert out["report_path"].stat().st_size > 0


def _silent_run(run_dir, recorded_steps: int, manifest_steps: int, damaged: int = -1):
    """A run of silent steps; the reply of step ``damaged`` recorded damaged (no longer a
    SpikeBatch)."""
    write_manifest(
        run_dir,
        {"name": "cut", "steps": manifest_steps, "config": {"loop": {"period_ms": 10.0}}},
    )
    rec = Recorder(run_dir)
    for k in range(recorded_steps):
        batch = SpikeBatch(step=k, run=RUN, t0_s=k * 0.01, t1_s=(k + 1) * 0.01).encode()
        rec.message("rx", "nv/s/culture/0/spikes", batch if k != damaged else b"\x81\xa1x\x01")
    rec.close()


def test_a_record_cut_short_is_analysed_as_far_as_it_goes_and_says_so(tmp_path):
    _silent_run(tmp_path, recorded_steps=100, manifest_steps=400)  # its hub killed, say
    out = analyze_run(tmp_path)
    note = "the record holds 100 of the run's 400 steps"
    assert out["metrics"]["record_short"].startswith(note)
    assert out["metrics"]["duration_s"] == pytest.approx(1.0)  # what it holds, not 4 s
    assert note in html.unescape(out["report_path"].read_text())


def test_a_whole_record_has_no_note(tmp_path):
    _silent_run(tmp_path, recorded_steps=100, manifest_steps=100)
    assert "record_short" not in analyze_run(tmp_path)["metrics"]


def test_a_damaged_message_is_left_out_counted_and_said(tmp_path):
    _silent_run(tmp_path, recorded_steps=100, manifest_steps=100, damaged=99)
    metrics = analyze_run(tmp_path)["metrics"]
    assert metrics["record_damaged"].startswith("1 recorded message is damaged (1 SpikeBatch)")
    assert metrics["duration_s"] == pytest.approx(0.99)  # the last batch's end: step 98's


def test_metrics_say_how_the_run_ended(tmp_path):
    _silent_run(tmp_path, recorded_steps=100, manifest_steps=100)
    assert analyze_run(tmp_path)["metrics"]["run_outcome"] == "unknown"
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    write_manifest(tmp_path, {**manifest, "outcome": "interrupted"})
    assert analyze_run(tmp_path)["metrics"]["run_outcome"] == "interrupted"


def test_a_record_that_holds_no_step_of_its_run_is_refused(tmp_path):
    _silent_run(tmp_path, recorded_steps=100, manifest_steps=100)
    (tmp_path / "record.nvrec").write_bytes(b"")  # lost whole, or never flushed
    with pytest.raises(AnalysisInputError, match="holds none of the run's 100 steps"):
        analyze_run(tmp_path)


def test_stimulus_onsets_are_window_starts_plus_pulse_onsets():
    msgs = [
        Stimulation(
            **W(3).stamp, channel=[1, 2], amplitude_ua=[1, 1], width_ms=[1, 1], onset_ms=[0, 0]
        ),
        Stimulation(**W(5).stamp, channel=[4], amplitude_ua=[1], width_ms=[1], onset_ms=[2.5]),
    ]
    onsets, chans = stimulus_onsets_ms(msgs)
    assert onsets.tolist() == [30.0, 52.5]
    assert chans.tolist() == [1, 2, 4]


def test_network_bursts_stretched_by_a_channel_bursting_throughout_are_said_so():
    from hub.analysis.bursts import detect_bursts
    from hub.analysis.network_bursts import detect_network_bursts
    from lab.run_analysis import extents_note
    from tests.analysis.analysis_synth import merge, network_burst

    starts = [2_000.0, 5_000.0, 9_000.0]
    spontaneous = merge(*[network_burst(range(4), s, 60.0) for s in starts])
    # a closed loop's stimulated channel: one burst of 10 s
    stimulated = merge(network_burst([9], 0.0, 10_000.0), spontaneous)
    plain = detect_network_bursts(detect_bursts(*spontaneous), 10)
    stretched = detect_network_bursts(detect_bursts(*stimulated), 10)
    assert extents_note(plain) == ""
    note = extents_note(stretched)
    assert note.startswith("network-burst extents span") and "Read the cores" in note


def test_a_long_analysis_says_each_stage_as_it_starts(tmp_path):
    _silent_run(tmp_path, recorded_steps=100, manifest_steps=100)
    stages: list[str] = []
    analyze_run(tmp_path, progress=stages.append)
    assert [s.split()[0] for s in stages] == ["reading", "analysing", "drawing", "writing"]
    assert stages[1].startswith("analysing 0 spikes on ")
