"""What each reported quantity and figure is: a label with its unit and a one-line definition.

The one place the report (``report.html``) and the docs take their wording from. A key not
listed here is shown as it is.
"""

from __future__ import annotations

#: metric key -> (label with unit, definition)
METRICS: dict[str, tuple[str, str]] = {
    "duration_s": ("recording analysed (s)", "from the first to the last spike batch"),
    "n_channels": ("channels", "neurons (simulated) or electrodes (an MEA) recorded"),
    "n_spikes": ("spikes", "all spikes in the analysed span"),
    "mfr_hz": ("MFR (Hz)", "mean firing rate: each channel's spikes / duration, averaged"),
    "mfr_sd_hz": ("MFR s.d. (Hz)", "spread of the channels' firing rates"),
    "mfr_exc_hz": ("MFR excitatory (Hz)", "mean firing rate of the excitatory channels"),
    "mfr_inh_hz": ("MFR inhibitory (Hz)", "mean firing rate of the inhibitory channels"),
    "n_bursts": ("single-channel bursts", "bursts of one channel (ISI-threshold detector)"),
    "mbr_per_min": (
        "MBR (/min)",
        "mean bursting rate: single-channel bursts per minute per channel (silent ones count 0)",
    ),
    "n_network_bursts": ("network bursts", "population events: many channels bursting at once"),
    "mnbr_per_min": ("MNBR (/min)", "mean network-burst rate: network bursts per minute"),
    "nb_duration_ms": (
        "network-burst duration (ms)",
        "mean extent, first to last spike of the bursts taking part",
    ),
    "nb_duration_sd_ms": ("network-burst duration s.d. (ms)", "spread of those durations"),
    "nb_core_duration_ms": (
        "network-burst core (ms)",
        "mean time the population stays at or above the detection threshold",
    ),
    "nb_participation": (
        "network-burst participation (fraction)",
        "mean share of channels taking part in a network burst",
    ),
    "nb_exc_spike_fraction": (
        "excitatory share of burst spikes",
        "fraction of the spikes inside network bursts fired by excitatory channels",
    ),
    "isi_median_ms": ("median ISI (ms)", "median interval between a channel's spikes"),
    "ibi_mean_ms": ("mean IBI (ms)", "mean interval between network-burst starts (their cores')"),
    "ibi_cv": (
        "IBI CV",
        "coefficient of variation of those intervals (0: periodic; none from fewer than two)",
    ),
    "psth_peak_ms": ("PSTH peak (ms)", "latency of the peak response after the stimuli"),
    "psth_not_computed": ("PSTH", "why no peri-stimulus histogram was computed"),
    "nb_extents_stretched": (
        "network-burst extents",
        "stretched by channels bursting throughout: what to read instead",
    ),
    "n_evoked_nb": (
        "evoked network bursts",
        "network bursts starting soon enough after a stimulus to count as evoked",
    ),
    "cat_spread": (
        "CAT spread (µm)",
        "how much the Center-of-Activity trajectories of network bursts differ (low: regular)",
    ),
    "cat_spread_evoked": ("CAT spread, evoked (µm)", "the same over evoked network bursts"),
    "cat_spread_spontaneous": (
        "CAT spread, spontaneous (µm)",
        "the same over spontaneous network bursts",
    ),
    "n_stimuli": ("stimuli", "distinct pulse onsets sent (pulses at the same time count once)"),
    "n_unknown_channel_spikes": (
        "spikes on unknown channels",
        "spikes on a channel the culture did not describe (left out)",
    ),
    "run_outcome": ("run outcome", "how the run ended (completed, interrupted, fault, ...)"),
    "record_short": ("record cut short", "the steps the record holds, when fewer than the run's"),
    "record_damaged": ("record damaged", "recorded messages that no longer decode (left out)"),
    "body_duration_s": ("robot: time (s)", "span of the recorded poses"),
    "body_distance_m": ("robot: distance (m)", "path length travelled"),
    "body_mean_speed_mps": ("robot: mean speed (m/s)", "distance / time"),
    "body_obstacle_entries": ("robot: obstacle entries", "times the robot entered an obstacle"),
    "body_arena_exits": ("robot: arena exits", "times the robot left the arena"),
    "body_wall_contacts": ("robot: wall contacts", "times the robot touched a solid wall"),
    "body_time_in_obstacles_s": ("robot: time in obstacles (s)", "time spent inside obstacles"),
    "body_time_outside_arena_s": ("robot: time outside (s)", "time spent outside the arena"),
    "body_coverage_fraction": (
        "robot: arena visited (fraction)",
        "share of the arena's grid cells the robot passed through",
    ),
    "body_coverage_cells_visited": ("robot: cells visited", "grid cells passed through"),
    "body_coverage_cells_total": ("robot: cells in the arena", "grid cells of the arena"),
    "body_coverage_cell_m": ("robot: coverage cell (m)", "side of a grid cell"),
}

#: timing key -> (label with unit, definition)
TIMING: dict[str, tuple[str, str]] = {
    "mode": ("mode", "lockstep (as fast as possible, exact) or realtime (wall-clock steps)"),
    "period_ms": ("period (ms)", "run time of one step"),
    "steps": ("steps", "steps completed"),
    "wall_s": ("wall time (s)", "how long the steps took, pauses included"),
    "paused_s": ("paused (s)", "time the steps were held by a pause (ctl, the dashboard)"),
    "steps_per_s": ("steps per second", "steps / (wall time less the time paused)"),
    "x_realtime": (
        "× real time",
        "run time simulated per second of wall time, the time paused left out",
    ),
    "hub_busy_s": ("hub busy (s)", "wall time the hub spent not waiting for replies"),
    "hub_cpu_s": ("hub CPU (s)", "CPU time of the hub's process during the steps"),
    "late_steps": (
        "late steps",
        "realtime: steps with a reply past its deadline, or that started more than a "
        "quarter period late",
    ),
    "late_share": ("late share", "late steps / steps"),
    "cpus": ("CPUs", "the CPUs the hub could run on"),
    "step_ms_median": ("step median (ms)", "median wall time of a step"),
    "step_ms_p99": ("step p99 (ms)", "99th percentile of a step's wall time"),
    "lateness_ms_median": ("start lateness median (ms)", "realtime: how late steps started"),
    "lateness_ms_p99": ("start lateness p99 (ms)", "realtime: 99th percentile of that"),
    "lateness_ms_max": ("start lateness max (ms)", "realtime: the latest start"),
    "round_trip_ms": (
        "reply round trip (ms)",
        "per endpoint, median / p99 / max of the time from its input's put to its reply",
    ),
    "outcome": (
        "outcome",
        "completed, stopped, interrupted or fault; unfinished: its hub ended without closing it",
    ),
    "reason": ("reason", "why the run ended so (a fault, a stop request)"),
    "record": (
        "record",
        "what the record holds, where it is less than the run: the analysis covers that",
    ),
    "start_utc": ("start (UTC)", "when the run began"),
    "end_utc": ("end (UTC)", "when the run ended"),
}

#: figure file stem -> caption
FIGURES: dict[str, str] = {
    "raster": "Raster: each spike as a tick, channel against time (red excitatory, blue "
    "inhibitory where the channels are a simulated culture's neurons; an MEA's electrodes "
    "are black); network bursts shaded (their cores darker) and marked ▼ above.",
    "raster_nb": "One second around the first network burst (shaded).",
    "rate": "Instantaneous firing rate of the population: the spikes per second of all "
    "channels together (and of the excitatory and the inhibitory ones together), in 10 ms "
    "bins; not per channel (the mean rates per channel are mfr_exc_hz and mfr_inh_hz).",
    "isi": "Inter-spike intervals within channels (ms).",
    "ibi": "Intervals between network-burst starts (their cores'; ms).",
    "psth": "Peri-stimulus time histogram: the population's response after each stimulus.",
    "cat_single": "The Center-of-Activity trajectory of the longest network burst on the "
    "culture (µm).",
    "cats_all": "The Center-of-Activity trajectories of every network burst.",
    "cats_evoked": "The Center-of-Activity trajectories of evoked network bursts.",
    "cats_spontaneous": "The Center-of-Activity trajectories of spontaneous network bursts.",
    "trajectory": "The robot's path in the arena, coloured by time; obstacles grey.",
    "loop": "The closed loop on one time axis: sensor ranges, the pulses they were coded "
    "into (by channel, amplitude as colour), the culture's Center of Activity, and the wheel "
    "commands decoded from it.",
    "stimulation_sites": "The culture's electrodes; those stimulated sized and coloured by "
    "the pulses they received.",
}


def metric(key: str, table: dict[str, tuple[str, str]] = METRICS) -> tuple[str, str]:
    """``(label, definition)`` of ``key``; the key itself and "" when not listed.

    Parameters
    ----------
    key : str
        The key, as in ``metrics.json`` or the manifest's timing.
    table : dict
        Where to look it up: :data:`METRICS` or :data:`TIMING`.
    """
    return table.get(key, (key, ""))
