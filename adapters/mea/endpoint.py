"""A living culture on a multi-electrode array as the loop's culture (``kind = "mea"``).

Each step's :class:`~hub.protocol.Stimulation` is checked pulse by pulse
(:mod:`adapters.mea.safety`: refused pulses are counted by reason, never clipped), turned
into charge-balanced biphasic pulses and fired at their onsets through the instrument's
driver (:mod:`adapters.mea.rhx`, :mod:`adapters.mea.lsl`; the interface:
:class:`~adapters.mea.driver.MeaDriver`). The spikes the instrument reports are placed in run time
through its clock (offset and drift fitted, in ``describe``'s counters) and answered per
window **after the window has passed** (``reply_margin_ms`` later, from a thread of the
endpoint's own): a device cannot know a window's spikes before its end. The hub therefore
gets step k's spikes during step k+1 — set ``loop.deadline_ms`` to one period plus the
margin and a little (``configs/hybrid_mea.toml``). A spike that reaches the endpoint after
its window was answered goes into the next batch at its true time (``late_channel``,
``late_t_ms``), counted as late data, never dropped.

Spikes are also streamed as they come (contract v4): every ``stream_spikes_ms`` at most,
the spikes read since are sent as a *part* of their window (``SpikeBatch(partial=True)``),
so the hub, its record and its observers have each spike within about that long of the
instrument's report, not a period later; the window's batch after its end holds the rest.

Parameters (``[culture.params]``): ``driver`` (``"rhx"`` or ``"lsl"``), ``layout_file`` (CSV
``name,x_um,y_um``; default the MCS 60-electrode layout on Intan ports A and B),
``reply_margin_ms`` (2), ``stream_spikes_ms`` (1; 0: no parts, one batch per window),
``[culture.params.safety]`` (:class:`~adapters.mea.safety.PulseLimits`); for ``rhx``:
``host`` (``127.0.0.1``), ``command_port`` (5000), ``spike_port`` (5002), ``freeze_s`` (1.5:
this process frozen that long, its stop guard makes the instrument safe; at least 1.2; 0:
off); for ``lsl`` (:mod:`adapters.mea.lsl`): ``spike_stream`` (""), ``spike_type``
(``"Spikes"``), ``spike_source_id`` (""), ``stim_outlet`` ("": record-only, every pulse
refused and counted), ``resolve_timeout_s`` (5), ``stim_wait_s`` (5). A key the driver does
not take is named.

Safety does not depend on the hub: stimulation stops (every electrode disabled, run mode
off) when the run ends, when the hub's liveliness vanishes, when no input comes for the
input timeout, and when the process ends.
"""

from __future__ import annotations

import heapq
import importlib.util
import logging
import math
import threading
import time
from collections import deque

import numpy as np

from adapters.mea.driver import MeaDriver
from adapters.mea.layout import ElectrodeLayout
from adapters.mea.rhx import COMMAND_TIMEOUT_S, RhxDriver
from adapters.mea.safety import PulseLimits, SafetyGate
from hub.config import ConfigError, EndpointSection, ExperimentConfig, check_value
from hub.endpoint import DeviceFault, Endpoint, RunRefused
from hub.protocol import Description, RunStart, SpikeBatch, StepWindow, Stimulation

log = logging.getLogger(__name__)

LOCKSTEP_REFUSAL = (
    "a culture on an MEA is a real device: it lives in real time and cannot wait for a "
    'lockstep loop; set loop.mode = "realtime"'
)
PARAMS = {"driver", "layout_file", "reply_margin_ms", "stream_spikes_ms", "safety"}  # any driver
DRIVER_PARAMS = {
    "rhx": {"host", "command_port", "spike_port", "freeze_s"},
    "lsl": {"spike_stream", "spike_type", "spike_source_id", "stim_outlet", "resolve_timeout_s",
            "stim_wait_s"},
}  # fmt: skip
CLOCK_SAMPLE_S = 0.5  # the instrument's clock is sampled this often during a run
DEVICE_BEAT_S = 0.1  # the device worker beats the driver's stop guard at least this often
# The shortest culture.params.freeze_s: a command's longest wait for its reply, and two
# beats (the worker beats between commands); shorter, a slow reply would pass for a freeze.
FREEZE_MIN_S = COMMAND_TIMEOUT_S + 2 * DEVICE_BEAT_S
FROZEN = (
    "this process stood (frozen) past culture.params.freeze_s, and its stop guard disabled "
    "every electrode and stopped run mode: the run's stimulation and clock cannot be trusted"
)
# Two threads, each with a heap of what falls due: one talks to the instrument (pulses, the
# clock), one answers windows and streams their parts, so that a slow instrument command
# never delays a reply.
LANES = {"fire": "device", "clock": "device", "reply": "replies", "part": "replies"}


class MeaEndpoint(Endpoint):
    """An MEA stimulator/recorder, served as the culture.

    Parameters
    ----------
    driver : MeaDriver
        Not yet opened (opened by :meth:`warm_up`): an :class:`~adapters.mea.rhx.RhxDriver`
        or an :class:`~adapters.mea.lsl.LslDriver`.
    limits : PulseLimits
    id : str
    reply_margin_ms : float
        How long after a window's end its spikes are answered.
    stream_spikes_ms : float
        Spikes go to the hub as parts of their window at most this often, as they come;
        0: only in the window's batch.
    """

    role, kind = "culture", "mea"

    def __init__(self, driver: MeaDriver, limits: PulseLimits, id: str = "0", *,
                 reply_margin_ms: float = 2.0, stream_spikes_ms: float = 1.0):  # fmt: skip
        super().__init__(id)
        self.driver, self.limits = driver, limits
        self.gate = SafetyGate(limits, driver.layout.n)
        self.reply_margin_s = reply_margin_ms / 1e3
        self.stream_s = stream_spikes_ms / 1e3
        self.late_spikes = 0
        self.parts_sent = 0
        self.trigger_lag_ms: deque[float] = deque(maxlen=100_000)  # due → trigger sent
        self.spike_wait_ms: deque[float] = deque(maxlen=100_000)  # spike read → batch sent
        self._opened = False
        self._origin = math.inf  # run time 0 on time.monotonic()'s clock
        # spikes taken from the driver and not yet sent: channel, run time (s), arrival
        self._carry: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._spikes = threading.Lock()  # one taker of spikes at a time (parts, answers)
        self._unanswered: dict[int, StepWindow] = {}  # stepped windows, by step
        self._next_part = -math.inf  # local time before which no part goes
        self._part_due = False  # a part is scheduled
        # per lane, a heap of (local time, seq, kind, payload)
        self._due: dict[str, list] = {lane: [] for lane in dict.fromkeys(LANES.values())}
        self._seq = 0
        self._timing = threading.Lock()  # guards the heaps and _due_now
        self._due_now: list[tuple[list, float]] = []  # pulses due at their input's arrival
        # each lane's worker sleeps until its earliest item, woken when an earlier one comes
        # (not by the other lane's: a wake-up takes the interpreter as a pulse goes out)
        self._wake = {lane: threading.Condition(self._timing) for lane in self._due}
        self._delivering = threading.Lock()  # one delivery (or stop) at a time
        self._workers: list[threading.Thread] = []
        self._closing = False

    @property
    def run_origin_s(self) -> float:
        """The run's time 0 on ``time.monotonic()``'s clock (the arrival of its first input
        less that input's window start; ``inf`` before it): pulses are due and spikes
        binned from here."""
        return self._origin

    @classmethod
    def check_config(cls, section: EndpointSection, cfg: ExperimentConfig) -> dict:
        """Check ``[culture.params]`` and the mode, opening nothing.

        Parameters
        ----------
        section : EndpointSection
            The ``[culture]`` section; its ``params`` are checked.
        cfg : ExperimentConfig
            The whole experiment: its loop's mode and deadline.

        Returns
        -------
        dict
            ``driver``, ``reply_margin_ms``, ``stream_spikes_ms``, ``layout_file``,
            ``safety`` and the driver's own keys, the defaults filled in and the values
            typed.

        Raises
        ------
        ConfigError
            Naming ``culture.params.<key>`` (a key the driver does not take, a bad value or
            file, pylsl missing for ``lsl``), ``loop.mode`` for a lockstep run, or
            ``loop.deadline_ms`` outside one to two periods.
        """
        if cfg.loop.mode != "realtime":
            raise ConfigError(f"loop.mode: {LOCKSTEP_REFUSAL}")
        if problem := cfg.loop.late_window_problem():  # an MEA answers after its window
            raise ConfigError(problem)
        params = dict(section.params)
        driver = params.get("driver", "rhx")
        if driver not in DRIVER_PARAMS:
            raise ConfigError(
                f"culture.params.driver must be one of {sorted(DRIVER_PARAMS)}, got {driver!r}"
            )
        unknown = sorted(set(params) - PARAMS - DRIVER_PARAMS[driver])
        if unknown:
            raise ConfigError(
                f"culture.params: unknown key(s) {unknown} for kind mea with driver "
                f"{driver!r} (it takes {sorted(PARAMS | DRIVER_PARAMS[driver])})"
            )
        out = {
            "driver": driver,
            "reply_margin_ms": check_value("culture.params.reply_margin_ms", float,
                                           params.get("reply_margin_ms", 2.0), ge=0),
            "stream_spikes_ms": check_value("culture.params.stream_spikes_ms", float,
                                            params.get("stream_spikes_ms", 1.0), ge=0),
            "layout_file": params.get("layout_file"),
            "safety": params.get("safety", {}),
        }  # fmt: skip
        if driver == "rhx":
            out |= {
                "host": check_value("culture.params.host", str, params.get("host", "127.0.0.1")),
                "command_port": check_value("culture.params.command_port", int,
                                            params.get("command_port", 5000), ge=1, le=65535),
                "spike_port": check_value("culture.params.spike_port", int,
                                          params.get("spike_port", 5002), ge=1, le=65535),
                "freeze_s": check_value("culture.params.freeze_s", float,
                                        params.get("freeze_s", 1.5), ge=0),
            }  # fmt: skip
            if 0 < out["freeze_s"] < FREEZE_MIN_S:
                raise ConfigError(
                    f"culture.params.freeze_s {out['freeze_s']:g} s is under "
                    f"{FREEZE_MIN_S:g} s (a command's {COMMAND_TIMEOUT_S:g} s wait for its "
                    "reply and two beats): the stop guard would disable an instrument that is "
                    "only slow to answer; 0 turns it off"
                )
        else:
            out |= cls._check_lsl(params)
        PulseLimits.from_params(out["safety"])
        if out["layout_file"] is not None:
            ElectrodeLayout.from_file(out["layout_file"])
        return out

    @staticmethod
    def _check_lsl(params: dict) -> dict:
        """The LSL driver's keys (``culture.params.*``), and pylsl installed."""
        out = {}
        for name, default in (("spike_stream", ""), ("spike_type", "Spikes"),
                              ("spike_source_id", ""), ("stim_outlet", "")):  # fmt: skip
            value = check_value(f"culture.params.{name}", str, params.get(name, default))
            if "'" in value:
                raise ConfigError(f"culture.params.{name} may not hold a quote: {value!r}")
            out[name] = value
        if not (out["spike_stream"] or out["spike_type"] or out["spike_source_id"]):
            raise ConfigError(
                "culture.params.spike_stream: the LSL spike stream needs a name, a type "
                "(spike_type) or a source id (spike_source_id)"
            )
        for name in ("resolve_timeout_s", "stim_wait_s"):
            out[name] = check_value(f"culture.params.{name}", float, params.get(name, 5.0), gt=0)
        if importlib.util.find_spec("pylsl") is None:
            raise ConfigError(
                "culture.params.driver = 'lsl' needs pylsl: pip install 'neuvision[lsl]'"
            )
        return out

    @classmethod
    def from_config(cls, section: EndpointSection, cfg: ExperimentConfig) -> MeaEndpoint:
        p = cls.check_config(section, cfg)
        layout = (
            ElectrodeLayout.from_file(p["layout_file"])
            if p["layout_file"]
            else ElectrodeLayout.mcs60()
        )
        if p["driver"] == "lsl":
            from adapters.mea.lsl import LslDriver  # pylsl: an optional dependency

            driver = LslDriver(
                layout, p["spike_stream"], p["spike_type"], p["spike_source_id"],
                p["stim_outlet"], p["resolve_timeout_s"], p["stim_wait_s"],
            )  # fmt: skip
        else:
            driver = RhxDriver(
                layout, p["host"], p["command_port"], p["spike_port"], freeze_s=p["freeze_s"]
            )
        limits = PulseLimits.from_params(p["safety"])
        return cls(
            driver, limits, section.id,
            reply_margin_ms=p["reply_margin_ms"], stream_spikes_ms=p["stream_spikes_ms"],
        )  # fmt: skip

    # ------------------------------------------------------------ the endpoint

    def warm_up(self) -> None:
        if not self._opened:
            if self.stream_s > 0:
                self.driver.on_spikes = self._spikes_came
            self.driver.open()
            self._opened = True
            for lane in self._due:
                worker = threading.Thread(
                    target=self._work, args=(lane,), name=f"mea-{lane}", daemon=True
                )
                worker.start()
                self._workers.append(worker)

    def describe(self) -> Description:
        self.warm_up()
        layout = self.driver.layout
        return Description(
            role="culture",
            id=self.id,
            kind=self.kind,
            channel=layout.channel,
            x_um=layout.x_um,
            y_um=layout.y_um,
            max_amplitude_ua=self.limits.max_amplitude_ua,
            max_width_ms=2 * self.limits.max_phase_us / 1e3,
            max_pulse_hz=self.limits.max_pulse_hz,
            realtime_only=True,
            answers_after_window=True,
        )

    def description(self) -> Description:
        desc = super().description()
        desc.counters["device"] = {
            **self.driver.report(),
            "pulses_admitted": self.gate.admitted,
            "pulses_refused": dict(self.gate.refused),
            "late_spikes": self.late_spikes,
            "spike_parts_sent": self.parts_sent,
        }
        for name, data in (("stim_to_trigger_ms", self.trigger_lag_ms),
                           ("spike_to_batch_ms", self.spike_wait_ms)):  # fmt: skip
            if data:
                values = np.array(data)
                desc.counters["device"][f"{name}_p50"] = float(np.percentile(values, 50))
                desc.counters["device"][f"{name}_p99"] = float(np.percentile(values, 99))
        return desc

    def start_run(self, run: RunStart) -> None:
        if run.mode != "realtime":
            raise RunRefused(LOCKSTEP_REFUSAL)
        if self.driver.fault is not None:
            raise RunRefused(f"the instrument failed: {self.driver.fault}")
        try:
            self.driver.start()
        except DeviceFault as exc:
            raise RunRefused(f"the instrument did not start: {exc}") from None
        with self._spikes:
            self.driver.take_spikes()  # what came before the run is not the run's
            self._carry = []
        with self._timing:
            self._origin = math.inf
            self._unanswered, self._next_part, self._part_due = {}, -math.inf, False
            self._due, self._due_now = {lane: [] for lane in self._due}, []
            self.gate = SafetyGate(self.limits, self.driver.layout.n)
            self._schedule(time.monotonic() + CLOCK_SAMPLE_S, "clock", None)

    def step(self, stim: Stimulation, window: StepWindow) -> None:
        now = time.monotonic()
        self._origin = min(self._origin, now - window.t0_s)
        by_onset: dict[float, list] = {}
        if not self.driver.stimulates and len(stim.channel):  # record-only: none delivered
            if not self.gate.refused["record_only"]:
                log.warning("pulse refused (record_only): the instrument has no stimulator")
            self.gate.refused["record_only"] += len(stim.channel)
            stim = Stimulation(**window.stamp)
        for c, a, w, o in zip(stim.channel, stim.amplitude_ua, stim.width_ms, stim.onset_ms,
                              strict=True):  # fmt: skip
            pulse = self.gate.admit(int(c), float(a), float(w), window.t0_s + float(o) / 1e3)
            if not isinstance(pulse, str):
                by_onset.setdefault(float(o), []).append(pulse)
        with self._timing:
            for onset_ms, pulses in by_onset.items():
                due = self._origin + window.t0_s + onset_ms / 1e3
                if due <= now:  # fired by handle() as soon as this input is done
                    self._due_now.append((pulses, now))
                else:
                    self._schedule(due, "fire", (pulses, due))
            self._schedule(self._origin + window.t1_s + self.reply_margin_s, "reply", window)
            self._unanswered[window.step] = window
        return None

    def handle(self, payload):
        """:meth:`Endpoint.handle`, then the pulses already due fired from this thread: a
        hand-over to the device thread cost ~0.25 ms before the instrument heard of them.
        They go out after the input's lock is released, so that a reply owed meanwhile does
        not wait for the instrument's round trip."""
        output = super().handle(payload)
        with self._timing:
            due_now, self._due_now = self._due_now, []
        for pulses, due in due_now:
            self._fire(pulses, due)
        return output

    def make_safe(self) -> None:
        """Nothing more delivered: pending pulses dropped, every electrode disabled. The
        recording goes on (a pause or an input timeout may be followed by more steps)."""
        with self._timing:
            device = [d for d in self._due["device"] if d[2] != "fire"]
            heapq.heapify(device)
            self._due["device"], self._due_now = device, []
        self._to_driver(self.driver.stop)

    def end_run(self) -> None:
        """The run is over: nothing pending, nothing delivered, the instrument out of its run."""
        with self._timing:
            self._due, self._due_now = {lane: [] for lane in self._due}, []
        self._to_driver(self.driver.finish)

    def _to_driver(self, call) -> None:
        if self._opened:
            try:
                with self._delivering:
                    call()
            except DeviceFault as exc:
                log.error("could not stop the stimulation: %s", exc)

    def _fire(self, pulses: list, due: float) -> None:
        """Deliver ``pulses`` now, from the calling thread; the instrument failing ends the
        run."""
        if self.driver.fault is not None:
            return
        try:
            with self._delivering:
                self.driver.deliver(pulses)
        except DeviceFault as exc:
            self._failed(exc)
            return
        self.trigger_lag_ms.append((time.monotonic() - due) * 1e3)

    def _failed(self, exc: DeviceFault) -> None:
        """End the endpoint with ``exc``; the first fault is the one raised (what follows it,
        such as spikes streamed on the session it closed, is its consequence)."""
        first = self.driver.fault  # the driver's own, when it found the instrument gone
        if first is None or first is exc:
            log.error("the instrument failed: %s", exc)
            self.driver.fault = exc
        else:
            log.warning("after the fault (%s), also: %s", first, exc)
        self.request_stop()

    def serve(self, *args, **kwargs) -> int:
        """:meth:`Endpoint.serve`; an instrument that failed ends it with that fault raised
        (``neuvision endpoint``: the fault named, exit status 2), not as a clean stop."""
        status = super().serve(*args, **kwargs)
        if self.driver.fault is not None:
            raise self.driver.fault
        return status

    def close(self) -> None:
        with self._timing:
            self._closing = True
            for wake in self._wake.values():
                wake.notify_all()
        for worker in self._workers:
            worker.join(timeout=2.0)
        self.driver.close()

    # ------------------------------------------------------------ timing

    def _schedule(self, at: float, kind: str, payload) -> None:
        self._seq += 1
        lane, item = LANES[kind], (at, self._seq, kind, payload)
        heapq.heappush(self._due[lane], item)
        if self._due[lane][0] is item:
            self._wake[lane].notify()

    def _work(self, lane: str) -> None:
        """:meth:`_serve_lane`; anything else it raises (a bug) ends the endpoint as a fault,
        named: a worker that died alone left the endpoint serving with no pulse fired and
        no clock sampled again."""
        try:
            self._serve_lane(lane)
        except Exception as exc:
            log.exception("the %s worker failed", lane)
            self._failed(DeviceFault(f"the endpoint's {lane} worker failed: {exc!r}"))
        finally:
            if lane == "device":
                self.driver.rest()  # its beats stop here, and not for a freeze

    def _serve_lane(self, lane: str) -> None:
        """What falls due in ``lane``: fire pulses at their onsets and sample the clock
        ("device"), or answer windows once they have passed ("replies")."""
        beats = lane == "device"  # it beats the driver's stop guard (adapters.guard)
        while True:
            with self._timing:
                while not self._closing:
                    try:
                        if beats and self.driver.beat():
                            kind = "frozen"  # the guard made the instrument safe meanwhile
                            break
                    except DeviceFault as exc:  # its stop guard lost, and not replaced
                        kind, payload = "lost", exc
                        break
                    now, due = time.monotonic(), self._due[lane]
                    if due and due[0][0] <= now:
                        _, _, kind, payload = heapq.heappop(due)
                        break
                    wait_s = due[0][0] - now if due else DEVICE_BEAT_S
                    self._wake[lane].wait(min(wait_s, DEVICE_BEAT_S) if beats else wait_s)
                else:
                    return
            if kind == "frozen":
                self._failed(DeviceFault(FROZEN))
                return
            if kind == "lost":
                self._failed(payload)
                return
            if kind == "fire":
                self._fire(*payload)
                if self.driver.fault is not None:
                    return
                continue
            if kind == "part":
                self._stream()
                continue
            try:
                if kind == "reply":
                    # after a delivery under way: the instrument's answer to it would
                    # otherwise wait for the interpreter this takes (~1 ms at 20 ms)
                    with self._delivering:
                        pass
                    self._answer(payload)
                else:
                    self.driver.sample_clock()
                    with self._timing:
                        if self.run is not None:
                            self._schedule(time.monotonic() + CLOCK_SAMPLE_S, "clock", None)
            except DeviceFault as exc:
                self._failed(exc)
                return

    def _taken(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The spikes not yet sent, those just read included: channel, time on
        ``time.monotonic()``'s clock (s; less :attr:`run_origin_s`, as it stands when they
        are binned, their run time), arrival (local). Called holding ``_spikes``."""
        channel, inst_s, arrived = self.driver.take_spikes()
        if channel.size:
            self._carry.append((channel, self.driver.clock.to_local(inst_s), arrived))
        if not self._carry:
            return np.zeros(0, np.uint32), np.zeros(0), np.zeros(0)
        if len(self._carry) > 1:
            self._carry = [tuple(np.concatenate(p) for p in zip(*self._carry, strict=True))]
        return self._carry[0]

    def _waited(self, arrived: np.ndarray) -> None:
        """How long these spikes waited in the endpoint, from their read to now."""
        self.spike_wait_ms.extend(((time.monotonic() - arrived) * 1e3).tolist())

    def _spikes_came(self) -> None:
        """The driver read spikes (its reader's thread): a part now, or once
        ``stream_spikes_ms`` has passed since the last one."""
        now = time.monotonic()
        with self._timing:
            if self._part_due or self.run is None:
                return
            if now < self._next_part:
                self._part_due = True
                self._schedule(self._next_part, "part", None)
                return
        try:
            self._stream()
        except Exception as exc:  # a bug; the reader must not die of it in silence
            log.exception("streaming spikes failed")
            self._failed(DeviceFault(f"streaming spikes failed: {exc!r}"))

    def _stream(self) -> None:
        """The spikes read so far that fall in a window not yet answered, each window's as
        a part of it; the others wait (a window to come, or late data for the next
        batch)."""
        with self._spikes:
            with self._timing:
                self._part_due = False
                self._next_part = time.monotonic() + self.stream_s
                windows = list(self._unanswered.values())
            run = self.run
            if run is None or not windows:  # before a step, run time is not yet known
                return
            channel, local_s, arrived = self._taken()
            run_s = local_s - self._origin
            sent = np.zeros(channel.size, bool)
            for window in windows:
                mine = (run_s >= window.t0_s) & (run_s < window.t1_s)
                if window.run != run.run or not mine.any():
                    continue
                part = SpikeBatch(**_in_window(window, channel, run_s, mine), partial=True)
                try:
                    self.reply(part)
                except TypeError:  # the run ended meanwhile: nothing owed
                    return
                self.parts_sent += 1
                self._waited(arrived[mine])
                sent |= mine
            if sent.any():
                keep = ~sent
                self._carry = [(channel[keep], local_s[keep], arrived[keep])]

    def _answer(self, window: StepWindow) -> None:
        """The window's spikes (instrument time → run time) not sent in parts, and late
        ones at their true time."""
        with self._spikes:
            with self._timing:
                self._unanswered.pop(window.step, None)
            run = self.run
            if run is None or run.run != window.run:  # the run ended meanwhile: nothing owed
                return
            channel, local_s, arrived = self._taken()
            run_s = local_s - self._origin
            mine = (run_s >= window.t0_s) & (run_s < window.t1_s)
            early = run_s < window.t0_s  # a window already answered: late data
            later = ~mine & ~early
            self._carry = [(channel[later], local_s[later], arrived[later])] if later.any() else []
            if mine.any():
                self._waited(arrived[mine])
            late_c, late_t = channel[early], run_s[early]
            self.late_spikes += int(late_c.size)
            batch = SpikeBatch(
                **_in_window(window, channel, run_s, mine),
                late_channel=late_c if late_c.size else None,
                late_t_ms=np.minimum((late_t - window.t0_s) * 1e3, 0.0) if late_c.size else None,
            )
            self.reply(batch)


def _in_window(window: StepWindow, channel: np.ndarray, run_s: np.ndarray, mine: np.ndarray):
    """A SpikeBatch's fields for ``window`` with the spikes ``mine``, in time order."""
    order = np.argsort(run_s[mine], kind="stable")
    return {
        **window.stamp,
        "channel": channel[mine][order],
        "t_ms": np.clip((run_s[mine][order] - window.t0_s) * 1e3, 0.0, None),
    }
