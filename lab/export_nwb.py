"""A recorded run as an NWB file (Neurodata Without Borders, read with pynwb or MATLAB).

``neuvision export RUN_DIR --nwb FILE`` writes, with pynwb (the NWB reference library):

- **units**: one unit per channel that fired, its spike times (s, run time); the
  **electrodes** table holds every channel of the culture with its position on the array
  (``rel_x``, ``rel_y`` in µm) and cell type, in one electrode group;
- **stimulation**: a time-intervals table, one row per pulse sent: start and stop (s),
  ``channel``, ``amplitude_ua``, ``width_ms``;
- **behavior** processing module: ``Position`` (``pose_xy``, metres in the arena's frame),
  ``CompassDirection`` (``heading``, radians, counter-clockwise from +x),
  ``sensor_ranges`` (metres, one column per range finder) and ``motor_commands``
  (left and right wheel speeds, m/s, each step's start);
- times: every time is run time, seconds from ``timestamps_reference_time``, which is the
  hub's wall clock (UTC) as step 0's first input left, run time 0 (the run's folder is made
  earlier, ``session_start_time``: the wait for the endpoints lies between them);
- metadata: the run id as ``identifier``, its start as ``session_start_time``, the
  experiment file's text as ``protocol`` (the resolved config as JSON when the file is
  gone), the manifest as JSON in ``notes``, and the culture as the ``subject`` (sex
  "U"; a simulated culture's date of birth is its run's start, a real one's is left to the
  lab to add).

No NWB extension is needed: everything is a core type.
"""

from __future__ import annotations

import datetime as dt
import io
import json
from pathlib import Path

import numpy as np

from hub.analysis.output import write_whole
from lab.experiment import Run

CULTURE_LOCATION = "in vitro culture (simulated or on a multi-electrode array)"


class ExportError(Exception):
    """The run cannot be exported (pynwb missing, not a run folder): said in one line."""


def export_nwb(run_dir: str | Path | Run, path: str | Path) -> Path:
    """Write a recorded run to an NWB file; return the file's path.

    A record cut short is exported as far as it goes, and its file's ``notes`` say so
    (``record_short``); so are damaged messages left out (``record_damaged``).

    Parameters
    ----------
    run_dir : path or Run
        A run folder, or a :class:`Run` opened on one.
    path : path
        The NWB file; one already there is replaced, once the new one is whole (it is
        built in memory first: about the file's size).

    Raises
    ------
    ExportError
        pynwb is not installed, ``run_dir`` is not a run folder or its record holds no
        step, or ``path`` cannot be written (a folder or a device is there, the file
        system refuses it).
    """
    try:
        import h5py
        from pynwb import NWBHDF5IO, NWBFile, TimeSeries
        from pynwb.behavior import CompassDirection, Position
        from pynwb.epoch import TimeIntervals
        from pynwb.file import Subject
        from pynwb.misc import Units
    except ImportError:
        raise ExportError(
            "NWB export needs pynwb: pip install 'neuvision[nwb]' (or pip install pynwb)"
        ) from None
    try:
        run = run_dir if isinstance(run_dir, Run) else Run.open(run_dir)
    except FileNotFoundError as exc:
        raise ExportError(str(exc)) from None
    run_dir = run.run_dir
    m = run.manifest
    if _holds_nothing(run):
        raise ExportError(
            f"{run_dir} holds no data to export: the run ended before its first step "
            f"({m.get('outcome', 'no outcome')}: {m.get('reason') or 'no reason recorded'})"
        )
    short = run.record.short_note()
    if short and not run.record.steps_recorded():
        raise ExportError(
            f"{run_dir} holds no data to export: its record holds none of the run's "
            f"{m['steps']} steps (empty, or damaged from its start)"
        )
    if short:
        m = {**m, "record_short": short}
    if damaged := run.record.damage_note():
        m = {**m, "record_damaged": damaged}
    start = dt.datetime.fromisoformat(m["start_utc"]) if m.get("start_utc") else None
    nwb = NWBFile(
        session_description=f"NeuVision run {m.get('name')} (seed {m.get('seed')}): "
        f"{m.get('outcome')} after {m.get('steps')} steps",
        identifier=m.get("run_id") or Path(run_dir).name,
        session_start_time=start or dt.datetime.now(dt.UTC),
        timestamps_reference_time=_run_time_zero(run) or start or dt.datetime.now(dt.UTC),
        experiment_description=_experiment_description(m),
        protocol=_protocol(m),
        notes=json.dumps(m, default=str),
        keywords=["closed loop", "neuro-robotics", "NeuVision"],
        subject=Subject(
            subject_id=_culture_id(m),
            description=_culture_description(m),
            sex="U",  # NWB's "unknown": a culture has none
            # a simulated culture is built when its run starts; a real one's age is the lab's
            date_of_birth=start if _simulated(m) else None,
        ),
    )
    dt_ms = _culture_dt_ms(m)
    nwb.units = Units(
        name="units",
        description="spikes of each channel (run time, s)",
        resolution=dt_ms / 1e3 if dt_ms else -1.0,  # NWB's "unknown"
    )
    _culture(nwb, run)
    _stimulation(nwb, run, TimeIntervals)
    _behaviour(nwb, run, Position, CompassDirection, TimeSeries)
    out = Path(path)
    if out.exists() and not out.is_file():  # a folder, a device: never replaced by the file
        raise ExportError(f"{out} is there and is not a file: give the NWB file to write")
    # Built in memory, then written whole (beside it, renamed when whole): a full disk
    # fails the write, not HDF5 in the middle of its file (which crashed the interpreter at
    # exit, after the error), and leaves no file.
    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as h5, NWBHDF5IO(file=h5, mode="w") as nwb_io:
        nwb_io.write(nwb)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        write_whole(out, buffer.getbuffer())
    except OSError as exc:
        raise ExportError(f"cannot write {out}: {exc.strerror or exc}") from None
    return out


def _holds_nothing(run: Run) -> bool:
    """The run recorded no step and no spike, pulse or pose (it ended before its first
    step): an NWB file of it would hold metadata only."""
    return (
        run.steps == 0
        and run.spikes[0].size == 0
        and run.stimulation["t_ms"].size == 0
        and run.trajectory[0].size == 0
    )


def _experiment_description(m: dict) -> str:
    c = m.get("config", {})

    def get(section: str, key: str):
        return c.get(section, {}).get(key)

    return (
        f"body {get('body', 'kind')}, culture {get('culture', 'kind')}, coding "
        f"{get('coding', 'scheme')}, decoding {get('decoding', 'scheme')}, "
        f"{get('loop', 'mode')} loop at {get('loop', 'period_ms')} ms"
    )


def _culture_config(m: dict) -> dict:
    params = m.get("config", {}).get("culture", {}).get("params") or {}
    config = params.get("config")
    return config if isinstance(config, dict) else {}


def _culture_dt_ms(m: dict) -> float | None:
    """The simulated culture's time step: its spike times' resolution (None: a device's)."""
    value = _culture_config(m).get("dt_ms")
    return float(value) if isinstance(value, int | float) else None


def _simulated(m: dict) -> bool:
    return m.get("config", {}).get("culture", {}).get("kind") == "sim_network"


def _run_time_zero(run: Run) -> dt.datetime | None:
    """The hub's wall clock as the run's first input left (step 0 starts: run time 0)."""
    first = next((f for f in run.record.frames if f.direction == "tx"), None)
    if first is None:
        return None
    return dt.datetime.fromtimestamp(first.t_wall_ns / 1e9, dt.UTC)


def _culture_id(m: dict) -> str:
    kind = m.get("config", {}).get("culture", {}).get("kind", "culture")
    return f"{kind} seed {m.get('seed')}"


def _culture_description(m: dict) -> str:
    kind = m.get("config", {}).get("culture", {}).get("kind")
    if _simulated(m):
        layout = _culture_config(m).get("layout", {})
        n = (layout.get("rows") or 0) * (layout.get("cols") or 0)
        model = _culture_config(m).get("neurons", {}).get("model", "izhikevich")
        return f"a simulated culture of {n or 'some'} {model} neurons (NeuVision sim_network)"
    return f"a culture served by a '{kind}' endpoint"


def _protocol(m: dict) -> str:
    """The experiment file's text as it was when the run started (kept in the manifest),
    then what ran: the config resolved (its ``extends``, ``--set`` and defaults applied,
    the culture's and the world's contents in place). Never the file as it is now."""
    resolved = json.dumps(m.get("config", {}), indent=2, default=str)
    text = m.get("config_text")
    if not text:  # a record from before the manifest kept the text
        return f"# the config that ran, resolved (JSON)\n{resolved}\n"
    return (
        f"# the experiment file {m.get('config_source')}, as the run started\n{text}\n"
        f"# the config that ran, resolved (extends, --set and defaults applied; JSON)\n"
        f"{resolved}\n"
    )


def _culture(nwb, run: Run) -> None:
    culture = run.record.descriptions().get("culture")
    channel, t_ms = run.spikes
    if culture is None or culture.channel is None:
        return
    device = nwb.create_device(name=f"culture {culture.kind}", description=culture.kind)
    group = nwb.create_electrode_group(
        name="culture",
        description="the culture's channels; their positions rel_x, rel_y in µm",
        location=CULTURE_LOCATION,
        device=device,
    )
    nwb.add_electrode_column(name="channel", description="the channel id on the wire")
    nwb.add_electrode_column(name="cell_type", description="0 excitatory, 1 inhibitory, -1 unknown")
    cell_type = culture.cell_type if culture.cell_type is not None else None
    for i, (c, x, y) in enumerate(zip(culture.channel, culture.x_um, culture.y_um, strict=True)):
        nwb.add_electrode(
            group=group,
            location=CULTURE_LOCATION,
            rel_x=float(x),
            rel_y=float(y),
            rel_z=0.0,
            channel=int(c),
            cell_type=int(cell_type[i]) if cell_type is not None else -1,
        )
    # The column typed even when no channel fired (an empty list has no type for HDF5).
    empty = {"data": np.empty(0, dtype=np.int64)} if channel.size == 0 else {}
    nwb.add_unit_column(name="channel", description="the channel id on the wire", **empty)
    index = {int(c): i for i, c in enumerate(culture.channel)}
    order = np.argsort(channel, kind="stable")
    channel, t_s = channel[order], t_ms[order] / 1e3
    ids, first = np.unique(channel, return_index=True)
    bounds = np.append(first, channel.size)
    for c, lo, hi in zip(ids, bounds[:-1], bounds[1:], strict=True):
        if int(c) in index:
            nwb.add_unit(
                spike_times=np.sort(t_s[lo:hi]), electrodes=[index[int(c)]], channel=int(c)
            )


def _stimulation(nwb, run: Run, TimeIntervals) -> None:
    pulses = run.stimulation
    if pulses["t_ms"].size == 0:
        return
    table = TimeIntervals(name="stimulation", description="every pulse the hub sent the culture")
    table.add_column(name="channel", description="the stimulated channel id")
    table.add_column(name="amplitude_ua", description="pulse amplitude (µA)")
    table.add_column(name="width_ms", description="pulse width (ms)")
    for t, c, a, w in zip(
        pulses["t_ms"], pulses["channel"], pulses["amplitude_ua"], pulses["width_ms"], strict=True
    ):
        table.add_row(
            start_time=t / 1e3,
            stop_time=(t + w) / 1e3,
            channel=int(c),
            amplitude_ua=float(a),
            width_ms=float(w),
        )
    nwb.add_time_intervals(table)


def _behaviour(nwb, run: Run, Position, CompassDirection, TimeSeries) -> None:
    t_s, poses = run.trajectory
    if t_s.size == 0:
        return
    module = nwb.create_processing_module(name="behavior", description="the robot in the loop")
    position = Position(name="Position")
    position.create_spatial_series(
        name="pose_xy",
        description="the robot's position",
        data=poses[:, :2],
        timestamps=t_s,
        reference_frame="the arena's centre, x to the right, y up (metres)",
        unit="meters",
    )
    module.add(position)
    heading = CompassDirection(name="CompassDirection")
    heading.create_spatial_series(
        name="heading",
        description="the robot's heading",
        data=poses[:, 2],
        timestamps=t_s,
        unit="radians",
        reference_frame="counter-clockwise from the arena's +x",
    )
    module.add(heading)
    sensor_t, ranges = run.sensors
    if sensor_t.size:
        module.add(
            TimeSeries(
                name="sensor_ranges",
                data=ranges,
                timestamps=sensor_t,
                unit="meters",
                description="each range finder's reading",
            )
        )
    motor_t, wheels = run.motor
    if motor_t.size:
        module.add(
            TimeSeries(
                name="motor_commands",
                data=wheels,
                timestamps=motor_t,
                unit="m/s",
                description="left and right wheel speeds sent, "
                "from each step's start (the final stop included)",
            )
        )
