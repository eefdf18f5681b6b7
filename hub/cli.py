"""neuvision: run closed-loop experiments between a spiking culture and a robot.

neuvision run CONFIG             hub + every local endpoint, with progress; records the run
neuvision hub CONFIG             the hub alone (endpoints started elsewhere)
neuvision endpoint ROLE CONFIG   one endpoint (body or culture) of CONFIG
neuvision record-info RUN_DIR    what a recorded run holds
neuvision emulate khepera|intan  a Khepera II/III on a pseudo-terminal, an Intan RHX on TCP
neuvision export RUN_DIR --nwb F  a recorded run as an NWB file
neuvision dashboard [CONFIG]     the live dashboard in a browser (--replay RUN_DIR: a recorded run)
neuvision ctl CMD [CONFIG]       status, pause, resume or stop a running hub
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from hub import stopping
from hub.bus import BusError
from hub.config import ConfigError, LoopSection, load_config
from hub.logs import install_log_cap
from hub.protocol import MODES
from hub.record import OutputError, make_output_folder
from hub.scheduling import endpoint_priority
from hub.security import PARTICIPANTS

EXIT_OK, EXIT_FAULT, EXIT_CONFIG, EXIT_INTERRUPTED = 0, 2, 3, 130
# `emulate intan`: the real-time priority an endpoint takes in a realtime run by default
EMULATOR_PRIORITY = endpoint_priority("realtime", LoopSection.realtime_priority)
log = logging.getLogger("neuvision")


class InputError(Exception):
    """A command's input that is not there or not what it must be (a run folder, a file):
    one line on stderr and exit status 3, like a config error."""


def _positive(kind: type, *, zero: bool = False) -> Callable[[str], float | int]:
    """An argparse type: a finite number of ``kind`` greater than 0 (or equal, with
    ``zero``)."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not (math.isfinite(value) and (value > 0 or (zero and value == 0))):
            raise argparse.ArgumentTypeError(
                f"must be >= 0, got {text}" if zero else f"must be > 0, got {text}"
            )
        return value

    parse.__name__ = kind.__name__  # what argparse names in its own messages
    return parse


def _overrides(args) -> list[str]:
    items = list(args.set or [])
    for flag, key in (
        ("duration_s", "experiment.duration_s"),
        ("seed", "experiment.seed"),
        ("mode", "loop.mode"),
        ("runs_dir", "experiment.runs_dir"),
        ("session", "bus.session"),
    ):
        value = getattr(args, flag, None)
        if value is not None:
            items.append(f"{key}={json.dumps(value)}")
    if getattr(args, "connect", None):
        items.append(f"bus.connect={json.dumps([_address(args.connect, args)])}")
    if getattr(args, "listen", None):
        items.append(f"bus.listen={json.dumps([_address(args.listen, args)])}")
    return items


def _address(text: str, args) -> str:
    """``HOST[:PORT]`` (or a Zenoh locator) as a Zenoh locator; the port defaults to the
    config's ``bus.listen`` port."""
    if "/" in text:
        return text  # already a locator: tcp/10.0.0.2:7447, tls/...
    if not text.strip() or text.endswith(":"):
        raise InputError(f"{text!r} is not an address: give HOST, HOST:PORT or [IPv6]:PORT")
    if text.startswith("["):  # [IPv6] or [IPv6]:PORT
        host, _, rest = text[1:].partition("]")
        port = rest[1:] if rest.startswith(":") else ""
    elif text.count(":") == 1:  # HOST:PORT
        host, _, port = text.partition(":")
    else:  # HOST, or a bare IPv6 address (no port)
        host, port = text, ""
    if ":" in host:
        host = f"[{host}]"  # Zenoh's locators bracket an IPv6 address
    if not port:
        listen = load_config(args.config, list(args.set or [])).bus.listen
        port = listen[0].rsplit(":", 1)[-1] if listen else "7447"
    scheme = (
        "tls" if load_config(args.config, list(args.set or [])).bus.security != "none" else "tcp"
    )
    return f"{scheme}/{host}:{port}"


def _add_config_args(p: argparse.ArgumentParser, *, shortcuts: bool = True) -> None:
    p.add_argument("config", nargs="?", help="experiment file (TOML); defaults if omitted")
    p.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="override a config key, e.g. --set loop.period_ms=20 (repeatable)",
    )
    if shortcuts:
        p.add_argument("--duration-s", type=float, help="experiment.duration_s")
        p.add_argument("--seed", type=int, help="experiment.seed")
        p.add_argument("--mode", choices=MODES, help="loop.mode")
        p.add_argument("--runs-dir", help="experiment.runs_dir")
        p.add_argument("--session", help="bus.session")


class _Parser(argparse.ArgumentParser):
    """An option refused is bad input: one line and exit status 3, as every other (argparse
    printed its usage and exited 2, the status of a fault)."""

    def error(self, message: str):
        command = self.prog.removeprefix("neuvision").strip()
        where = f"{command}: " if command else ""
        self.exit(
            EXIT_CONFIG,
            f"neuvision: {where}{' '.join(message.split())} ({self.prog} --help)\n",
        )


def build_parser() -> argparse.ArgumentParser:
    """The ``neuvision`` command line: every command's options and help (refused options
    exit with status 3, see :data:`EXIT_CONFIG`)."""
    parser = _Parser(
        prog="neuvision",
        description="Closed-loop experiments between a spiking culture (simulated, or a real "
        "one on an MEA) and a robot (simulated, or a real Khepera), looped by a hub over Zenoh. "
        "Every run is recorded in a folder of its own.",
        epilog="Start with: neuvision run configs/closed_loop.toml  (the paper's closed loop, "
        "60 s). 'neuvision COMMAND --help' for each command; the README and docs/ for the rest. "
        "Exit status: 0 done, 2 fault, 3 bad input, 130 interrupted.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser(
        "run",
        help="run an experiment: hub and local endpoints",
        description="Run an experiment: the hub in this process, each local endpoint "
        '(launch = "local") as a process of its own, a progress line, and a run folder '
        "(record, manifest, summary, figures). Ctrl-C ends it cleanly.",
    )
    _add_config_args(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_dashboard_flag(p)
    p = sub.add_parser(
        "hub",
        help="run the hub alone (endpoints started elsewhere)",
        description="Run only the hub of an experiment: its endpoints are started elsewhere "
        "(neuvision endpoint ROLE CONFIG --connect HOST, on this or another machine) and "
        "found on the bus session. Records the run as 'run' does.",
    )
    _add_config_args(p)
    p.add_argument(
        "--listen",
        metavar="ADDR[:PORT]",
        help="where to listen for endpoints (bus.listen), e.g. 0.0.0.0:7447 for other hosts",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_dashboard_flag(p)
    p = sub.add_parser(
        "endpoint",
        help="serve one endpoint of a config",
        description="Serve the body or the culture of an experiment on the bus until "
        "stopped (SIGINT/SIGTERM), for a hub started with 'neuvision hub'.",
    )
    p.add_argument("role", choices=("body", "culture"), help="which endpoint of CONFIG")
    _add_participant_args(p)
    p = sub.add_parser(
        "observe",
        help="serve live burst detection for a hub (the burst observer)",
        description="Serve the burst observer on the bus until stopped (SIGINT/SIGTERM): it "
        "reads the culture's spikes of each run, detects bursts and network bursts as they "
        "complete and reports them to the hub, which records them. The hub starts one itself "
        '(online.launch = "local"); this is for a hub whose observer runs elsewhere '
        '(online.launch = "external").',
    )
    p.add_argument("what", choices=("bursts",), help="what to observe")
    _add_participant_args(p)
    p = sub.add_parser(
        "record-info",
        help="summarise a recorded run",
        description="What a run folder's record holds: messages by kind and verdict, events, "
        "the manifest's outcome (JSON on stdout).",
    )
    p.add_argument("run_dir", help="a run folder")
    p = sub.add_parser(
        "compare",
        help="run conditions over several seeds and compare them",
        description="Run each experiment file (a condition: e.g. closed_loop.toml against "
        "its blind control) on seeds 1..N, every run recorded; then table each condition's "
        "metrics (mean ± s.d. over seeds; a permutation test of each between the first "
        "condition and each other) in compare.md and compare.json, and draw every path in "
        "trajectories.png. A failed run is listed with its reason, and the command exits 2.",
    )
    p.add_argument("configs", nargs="+", help="experiment files, one per condition")
    p.add_argument("--seeds", type=int, default=8, help="seeds 1..N per condition (default 8)")
    p.add_argument("--jobs", type=_positive(int), help="runs at a time (default: the cores)")
    p.add_argument("--out", type=Path, help="folder for the comparison (default: a new one)")
    p.add_argument("--duration-s", type=float, help="experiment.duration_s for every run")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override for every run")
    p = sub.add_parser(
        "analyze",
        help="metrics, figures and report.html of a recorded run",
        description="Analyse a recorded run: firing and burst statistics of the culture, "
        "network bursts, Center of Activity trajectories, the PSTH when stimuli are far enough "
        "apart, and for a closed loop the loop figure and the stimulation sites. Writes "
        "metrics.json, figures and report.html.",
    )
    p.add_argument("run_dir", type=Path, help="a run folder")
    p.add_argument("--out", type=Path, help="output folder (default: RUN_DIR/analysis)")
    p = sub.add_parser(
        "export",
        help="a recorded run as an NWB file",
        description="Write a recorded run as an NWB file (Neurodata Without Borders): spikes "
        "as units with their electrodes' positions, every pulse sent, the robot's pose, "
        "sensor ranges and motor commands, the experiment file and the manifest (needs pynwb: "
        "pip install 'neuvision[nwb]').",
    )
    p.add_argument("run_dir", type=Path, help="a run folder")
    p.add_argument("--nwb", type=Path, required=True, metavar="FILE", help="the NWB file to write")
    p = sub.add_parser(
        "emulate",
        help="emulate a device on this machine (a Khepera on a pseudo-terminal, an Intan "
        "RHX on loopback TCP)",
        description="Emulate a device. khepera: a pseudo-terminal that speaks a Khepera II's "
        "(with --dialect khepera3, a Khepera III's) serial protocol, answered by a simulated "
        "robot in a world, in real time; prints the device path (give it as "
        "body.params.port, or use --link). intan: the Intan RHX "
        "software's TCP command and spike ports on loopback, answered by a simulated culture "
        "seen through its virtual MEA, in real time.",
    )
    p.add_argument("device", choices=("khepera", "intan"))
    p.add_argument(
        "--culture", help="intan: the culture file behind the MEA (default culture_1024.toml)"
    )
    p.add_argument("--command-port", type=int, help="intan: RHX command port (default 5000)")
    p.add_argument("--spike-port", type=int, help="intan: RHX spike port (default 5002)")
    p.add_argument(
        "--realtime-priority",
        type=int,
        metavar="P",
        help="intan: SCHED_FIFO priority of the emulator's threads (0: ordinary scheduling; "
        f"default {EMULATOR_PRIORITY}, the endpoints' in a realtime run), so that a realtime "
        "run's raised threads do not starve it (an instrument has a machine of its own)",
    )
    p.add_argument(
        "--world",
        help="world file with the robot (default: the dialect's robot in the paper's "
        "arena, configs/worlds/DIALECT.toml)",
    )
    p.add_argument(
        "--dialect",
        choices=("khepera2", "khepera3"),
        help="khepera: the robot's model (default khepera2)",
    )
    p.add_argument(
        "--ir-table",
        metavar="FILE",
        help="khepera: the IR response, CSV distance_m,value (required for khepera3, which has "
        "none published; the adapter's body.params.ir_table_file format)",
    )
    p.add_argument(
        "--baud", type=int, help="take each exchange's byte time at this baud (default: no delay)"
    )
    p.add_argument(
        "--stop-bits",
        type=int,
        choices=(1, 2),
        help="for the byte time (default the model's: 2 for khepera2, 1 for khepera3)",
    )
    p.add_argument("--link", help="also make this symlink to the device (removed at exit)")
    p.add_argument(
        "--garbage-every",
        type=int,
        metavar="N",
        help="khepera fault: garbage before every N-th reply",
    )
    p.add_argument(
        "--drop-every", type=int, metavar="N", help="khepera fault: drop every N-th reply"
    )
    p.add_argument(
        "--seed",
        type=_positive(int, zero=True),
        default=None,
        help="the emulator's noise (khepera: range-finder noise of the world, default 0; "
        "intan: the culture's seed, default 1)",
    )
    p = sub.add_parser(
        "certs",
        help="make a certificate authority and a certificate per participant (bus.security)",
        description="Make a small certificate authority in DIR (kept if there) and, for "
        "each role, ROLE.pem and ROLE.key, for runs with bus.security = 'mtls' and "
        "bus.certs_dir = DIR. Copy to each machine ca.pem and its participant's two files; "
        "keep ca.key where certificates are made. With --passwords, also a password per "
        "role (ROLE.password) and the hub's dictionary of them (passwords), for "
        "bus.security = 'password': then a machine needs ca.pem and its ROLE.password, the "
        "hub's machine hub.pem, hub.key and passwords. Needs 'cryptography' (pip install "
        "'neuvision[security]').",
    )
    p.add_argument("dir", type=Path, help="folder of the certificates")
    p.add_argument(
        "--roles",
        default=",".join(PARTICIPANTS),
        help=f"comma-separated, of {','.join(PARTICIPANTS)} (default: all)",
    )
    p.add_argument(
        "--hub-hosts",
        help="comma-separated names and addresses other machines reach the hub by "
        "(127.0.0.1 and localhost always added, for what the hub starts itself; default: "
        "those and this machine's name)",
    )
    p.add_argument("--days", type=int, default=365, help="validity (default 365)")
    p.add_argument(
        "--passwords",
        action="store_true",
        help="also a fresh password per role, for bus.security = 'password'",
    )
    p = sub.add_parser(
        "reproduce",
        help="run the paper's validation of the simulated culture",
        description="The paper's validation of the simulated culture (docs/validation.md): "
        "15 min of spontaneous activity, then 10 ms, 100 µA pulses at 0.2 Hz into one or four "
        "neurons, excitatory or inhibitory. Writes reproduction.md (each figure against the "
        "paper's, judged within ±30 % for one seed; with --seeds, within ±20 % on every "
        "seed), reproduction.json, figures and report.html.",
    )
    p.add_argument("--out", type=Path, help="output folder (default: a new run folder)")
    p.add_argument("--quick", action="store_true", help="a shortened version (for tests)")
    p.add_argument(
        "--seed", type=_positive(int, zero=True), default=1, help="the culture's seed (default 1)"
    )
    p.add_argument(
        "--seeds", help="several seeds, e.g. 1-6 or 1,3,5: a table per seed and mean ± s.d."
    )
    p.add_argument(
        "--jobs", type=_positive(int), default=1, help="seeds reproduced at once (--seeds)"
    )
    p.add_argument("--culture", type=Path, help="culture file (default configs/culture_1024.toml)")
    _add_dashboard_commands(sub)
    return parser


def _add_participant_args(p: argparse.ArgumentParser) -> None:
    """CONFIG and what a participant started apart from its hub needs to find it."""
    _add_config_args(p, shortcuts=False)
    p.add_argument(
        "--connect",
        metavar="HOST[:PORT]",
        help="where the hub listens (bus.connect; the port defaults to bus.listen's)",
    )
    p.add_argument("--session", help="bus.session")
    p.add_argument("--once", action="store_true", help="exit when the first run ends")


def _add_dashboard_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--dashboard",
        action="store_true",
        help="also serve the live dashboard (dashboard.port, default 8447) while the run goes",
    )


def _add_dashboard_commands(sub) -> None:
    p = sub.add_parser(
        "dashboard",
        help="the live dashboard in a browser, or the replay of a recorded run",
        description="Serve a page (on localhost; dashboard.host/port) that shows a run live: the "
        "arena and the robot, the culture's activity and Center of Activity, a raster, the "
        "rates, the loop's timing and each endpoint; with pause, resume and stop. It observes "
        "the bus and may run on another machine than the hub (--connect). With --replay it "
        "plays a recorded run through the same page, with a time slider.",
        epilog="Without --connect, the hub of the session (--session) that a 'neuvision run' "
        "on this machine started is found where that run says it listens.",
    )
    _add_config_args(p, shortcuts=False)
    p.add_argument("--session", help="bus.session")
    p.add_argument("--connect", metavar="HOST[:PORT]", help="where the hub listens (bus.connect)")
    p.add_argument("--port", type=int, help="dashboard.port (0: a free one)")
    p.add_argument("--host", help="dashboard.host (0.0.0.0: reachable from other machines)")
    p.add_argument("--replay", metavar="RUN_DIR", help="replay this run folder instead")
    p.add_argument("--speed", type=float, default=1.0, help="replay speed, x real time")
    p = sub.add_parser(
        "ctl",
        help="status, pause, resume or stop a running hub",
        description="Send a command to a running hub's control key (hub/control) and print "
        "its reply as JSON: status (the hub's state and counters), pause (the loop holds, the "
        "robot stops), resume, stop (the run ends as 'stopped' after the current step); the "
        "reply's state is the one the command leads to (paused, running, stopping). Exit "
        "status 0 when the hub "
        "took the command, 2 when it refused it or no hub answered.",
        epilog="Without --connect, the hub of the session (--session) that a 'neuvision run' "
        "on this machine started is found where that run says it listens.",
    )
    p.add_argument("cmd", choices=("status", "pause", "resume", "stop"))
    _add_config_args(p, shortcuts=False)
    p.add_argument("--session", help="bus.session")
    p.add_argument("--connect", metavar="HOST[:PORT]", help="where the hub listens (bus.connect)")
    p.add_argument(
        "--timeout-s", type=_positive(float), default=5.0, help="how long to wait for the hub"
    )


def main(argv: list[str] | None = None) -> int:
    """Run one ``neuvision`` command and return its exit status.

    Bad input (a config error, a missing run folder, an unwritable output folder) is one
    line on stderr and status 3; a bus error 2; an interrupt while starting 130 (an
    endpoint or observer: 0). Called from the main thread, it installs the signal handlers
    that make SIGINT, SIGTERM (and, for ``run``/``hub``, SIGHUP) stop a command cleanly.

    Parameters
    ----------
    argv : list of str, optional
        The arguments after ``neuvision``; ``sys.argv[1:]`` when None.
    """
    in_main_thread = threading.current_thread() is threading.main_thread()
    stopping.forget_start_signal()
    if in_main_thread and signal.getsignal(signal.SIGINT) in (
        signal.SIG_IGN,
        signal.default_int_handler,
    ):
        # Ctrl-C stops a command while it starts up as it does once the command's own
        # handler is in; even when the parent left it ignored (a shell does so for a
        # background job), and remembered where a library swallows its KeyboardInterrupt.
        signal.signal(signal.SIGINT, stopping.interrupt_while_starting)
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:  # said by the command's own parser, which names its own --help
        commands = parser._subparsers._group_actions[0].choices
        commands[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    if in_main_thread and args.command in ("endpoint", "observe", "run", "hub"):
        # Its runner stops it with SIGTERM, maybe while it starts up (its imports, compiled
        # kernels, its model): as Ctrl-C then (below), not a death by signal. A run's
        # terminal closed (SIGHUP: a window shut, ssh dropped) ends it the same way.
        signal.signal(signal.SIGTERM, stopping.interrupt_while_starting)
        if args.command in ("run", "hub"):
            signal.signal(signal.SIGHUP, stopping.interrupt_while_starting)
    # Schemes and endpoint kinds named module:attr may live in the user's own folder: it
    # is searched last, so that a folder holding another copy of NeuVision (a clone of
    # another version) cannot mix its modules with the installed ones.
    if "" not in sys.path and os.getcwd() not in sys.path:
        sys.path.append(os.getcwd())
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(name)s %(levelname)s: %(message)s",
        stream=sys.stderr,
    )
    install_log_cap()  # a stranger's payload must not make a 500 kB log line
    try:
        try:
            return COMMANDS[args.command](args)
        except Exception as exc:
            if stopping.signalled_while_starting():  # a library made the interrupt its error
                return _interrupted(args, exc)
            raise
    except ConfigError as exc:
        print(f"neuvision: config error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_CONFIG
    except (InputError, OutputError) as exc:
        print(f"neuvision: {_one_line(exc)}", file=sys.stderr)
        return EXIT_CONFIG
    except BusError as exc:  # a port taken, a router unreachable: one line, no traceback
        print(f"neuvision: {_one_line(exc)}", file=sys.stderr)
        return EXIT_FAULT
    except KeyboardInterrupt:
        return _interrupted(args)
    finally:
        stopping.forget_start_signal()  # for a command run after this one in the same process


def _interrupted(args, exc: BaseException | None = None) -> int:
    """Ctrl-C (or the runner's SIGTERM) before a command's own handler is in place (its
    imports, an endpoint building its model): one line. An endpoint asked to stop exits 0,
    as it does once serving (docs/contract.md); any other command 130."""
    why = f" ({type(exc).__name__}: {_one_line(exc)})" if exc is not None else ""
    print(f"neuvision: interrupted{why}", file=sys.stderr)
    # CPython 3.11 notes a KeyboardInterrupt that ends an exec() of a string (a dataclass's
    # generated methods, as numba's imports make them) as unhandled even once caught, and
    # the process then kills itself by SIGINT at exit; the next exec of a string clears it.
    exec("pass")
    return EXIT_OK if args.command in ("endpoint", "observe") else EXIT_INTERRUPTED


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def _emit(text: str) -> None:
    """Print a command's result on stdout; a reader that left (``| head``) is no error."""
    try:
        print(text, flush=True)
    except BrokenPipeError:
        # Python's own flush at exit would fail again: stdout goes nowhere from here.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


# --------------------------------------------------------------------------- commands


def cmd_endpoint(args) -> int:
    """``neuvision endpoint ROLE CONFIG``: serve one endpoint until stopped; the status
    ``serve`` returns, or 2 on a device fault."""
    from hub.bus import check_security_files
    from hub.endpoint import DeviceFault
    from hub.launch import make_endpoint, settings_digest, settings_digests

    cfg = load_config(args.config, _overrides(args))
    check_security_files(cfg.bus, [args.role])  # before its model is built
    priority = endpoint_priority(cfg.loop.mode, cfg.loop.realtime_priority)
    cpus = cfg.endpoint(args.role).cpus
    try:
        endpoint = make_endpoint(cfg, args.role)
        # its hub refuses it if it serves other settings than the hub's experiment
        endpoint.settings_digest = settings_digest(cfg, args.role)
        endpoint.settings_digests = settings_digests(cfg, args.role)
        return endpoint.serve(
            cfg.bus,
            realtime_priority=priority,
            cpus=cpus,
            keep_cpus_awake=cfg.loop.keep_cpus_awake,
            once=args.once,
        )
    except DeviceFault as exc:
        print(f"neuvision: {args.role} device fault: {_one_line(exc)}", file=sys.stderr)
        return EXIT_FAULT


def cmd_observe(args) -> int:
    """``neuvision observe bursts CONFIG``: serve the burst observer until stopped."""
    from hub.burst_observer import main as observe_bursts
    from hub.bus import check_security_files

    cfg = load_config(args.config, _overrides(args))
    check_security_files(cfg.bus, ["observer"])
    return observe_bursts(cfg.bus, once=args.once)


def cmd_hub(args, local: bool = False) -> int:
    """``neuvision hub CONFIG``: run and record an experiment whose endpoints are started
    elsewhere; 0 when it ends, 2 on a fault, 130 when interrupted.

    Parameters
    ----------
    args : argparse.Namespace
        The command's parsed arguments.
    local : bool
        Also start every ``launch = "local"`` endpoint (``neuvision run``).
    """
    from lab.experiment import run_experiment

    result = run_experiment(
        args.config,
        _overrides(args),
        local=local,
        progress=None if args.quiet else ProgressBar(),
        announce=lambda line: print(f"neuvision: {line}", file=sys.stderr),
        dashboard=args.dashboard,
    )
    print(_result_line(result), file=sys.stderr)
    if result.outcome == "fault":
        print(f"neuvision: run failed: {result.reason}", file=sys.stderr)
        return EXIT_FAULT
    return EXIT_INTERRUPTED if result.outcome == "interrupted" else EXIT_OK


def cmd_run(args) -> int:
    """``neuvision run CONFIG``: :func:`cmd_hub` with the local endpoints started too."""
    return cmd_hub(args, local=True)


def cmd_record_info(args) -> int:
    """``neuvision record-info RUN_DIR``: :func:`record_summary` as JSON on stdout."""
    from hub.record import read_run

    run_dir = _run_folder(args.run_dir)
    try:
        rec = read_run(run_dir)
    except (OSError, ValueError) as exc:
        log.debug("reading %s", run_dir, exc_info=True)
        raise InputError(f"cannot read the run in {run_dir}: {exc}") from None
    _emit(json.dumps(record_summary(rec), indent=2))
    return EXIT_OK


def _run_folder(path) -> Path:
    """``path`` if it is a run folder (it holds a manifest or a record), else InputError."""
    from hub.record import MANIFEST_FILE, RECORD_FILE

    run_dir = Path(path)
    if not run_dir.exists():
        raise InputError(f"run folder {run_dir} not found")
    if not run_dir.is_dir():
        raise InputError(f"{run_dir} is not a run folder (not a folder)")
    if not ((run_dir / MANIFEST_FILE).exists() or (run_dir / RECORD_FILE).exists()):
        raise InputError(
            f"{run_dir} is not a run folder (no {MANIFEST_FILE} or {RECORD_FILE} in it)"
        )
    return run_dir


def _recorded_run(path, doing: str) -> Path:
    """``path`` if it is a run folder with a record, else InputError (a run made with
    ``record.enabled = false`` has a manifest only)."""
    from hub.record import RECORD_FILE

    run_dir = _run_folder(path)
    if not (run_dir / RECORD_FILE).exists():
        raise InputError(
            f"{run_dir} holds no {RECORD_FILE} (a run made with record.enabled = false "
            f"records its manifest only): nothing to {doing}"
        )
    _readable_run(run_dir)
    return run_dir


def _readable_run(run_dir: Path) -> None:
    """InputError unless the run folder's manifest and its record's header can be read
    (a damaged file, or one that is not a NeuVision run's, is named in one line)."""
    from hub.record import RECORD_FILE, RunReadError, iter_frames, read_manifest

    try:
        read_manifest(run_dir)
        if (run_dir / RECORD_FILE).exists():
            with contextlib.closing(iter_frames(run_dir / RECORD_FILE)) as frames:
                next(frames, None)
    except (OSError, RunReadError) as exc:
        raise InputError(f"cannot read the run in {run_dir}: {exc}") from None


def record_summary(rec) -> dict:
    """What a record holds: outcome, timing, counts of frames per key and events."""
    per_key: dict[str, int] = {}
    events: dict[str, int] = {}
    for f in rec.frames:
        if f.direction == "ev":
            events[f.key] = events.get(f.key, 0) + 1
        else:
            name = f"{f.direction} {f.key}"
            per_key[name] = per_key.get(name, 0) + 1
    m = rec.manifest
    span_s = (rec.frames[-1].t_wall_ns - rec.frames[0].t_wall_ns) / 1e9 if rec.frames else 0.0
    short = rec.short_note()
    return {
        "run_dir": str(rec.run_dir),
        "name": m.get("name"),
        "outcome": m.get("outcome", "unknown (no manifest)"),
        "reason": m.get("reason", ""),
        **(
            {"local_endpoint_exits": m["local_endpoint_exits"]}
            if "local_endpoint_exits" in m
            else {}
        ),
        **({"rejoins": m["rejoins"]} if m.get("rejoins") else {}),
        "start_utc": m.get("start_utc"),
        "end_utc": m.get("end_utc"),
        "steps": m.get("steps"),
        "timing": m.get("timing", {}),
        "counts": m.get("counts", {}),
        "frames": len(rec.frames),
        "steps_recorded": rec.steps_recorded(),
        **({"record_short": short} if short else {}),
        **({"record_damaged": damaged} if (damaged := rec.damage_note()) else {}),
        "recorded_span_s": round(span_s, 3),
        "messages": per_key,
        "events": events,
    }


def _result_line(result) -> str:
    from hub.record import RECORD_FILE

    t = result.timing
    if (result.run_dir / RECORD_FILE).exists():
        where = f"record in {result.run_dir}"
    else:
        where = f"nothing recorded (record.enabled = false): manifest and logs in {result.run_dir}"
    paused_s = t.get("paused_s", 0.0)
    paused = f" ({paused_s:.1f} s of it paused)" if paused_s >= 0.05 else ""
    return (
        f"neuvision: {result.outcome} after {result.steps} steps, "
        f"{t.get('wall_s', 0):.1f} s wall{paused}, {t.get('x_realtime', 0):.1f}x real time, "
        f"{t.get('late_steps', 0)} late step(s){_lost_said(result.counts)}; {where}"
    )


def _lost_said(counts: dict) -> str:
    """ ", 799 coding messages dropped (limit), 3 culture replies missing, 12 culture replies
    late (the policy stood in)" or "": what did not
    happen as configured, said where the run's last line is read, not only in its summary."""
    parts = []
    for role, kinds in sorted((counts or {}).get("dropped", {}).items()):
        for kind, n in sorted(kinds.items()):
            parts.append(f"{n} {role} message(s) dropped ({kind})")
    for role, n in sorted((counts or {}).get("missing", {}).items()):
        parts.append(f"{n} {role} repl(ies) missing")
    for role, n in sorted((counts or {}).get("late", {}).items()):
        if n:
            parts.append(f"{n} {role} repl(ies) late (the policy stood in)")
    return "".join(f", {p}" for p in parts)


class ProgressBar:
    """Simulated time, steps/s and late steps on stderr (a line every 5 s if not a TTY)."""

    def __init__(self, stream=sys.stderr):
        self.stream = stream
        self.tty = stream.isatty()
        self._last_line = 0.0

    def __call__(self, p) -> None:
        share = p.step / p.n_steps if p.n_steps else 0.0
        filled = int(30 * share)
        text = (
            f"[{'#' * filled}{'-' * (30 - filled)}] {100 * share:5.1f}%  "
            f"t={p.t_s:8.2f} s  {p.steps_per_s:7.0f} steps/s  late {p.late_steps}  {p.state}"
        )
        try:
            if self.tty:
                self.stream.write("\r" + text)
                self.stream.flush()
            elif time.monotonic() - self._last_line >= 5.0:
                self._last_line = time.monotonic()
                print(text, file=self.stream, flush=True)
        except OSError:  # the terminal is gone (closed, ssh dropped): the run goes on
            self.tty, self._last_line = False, math.inf

    def close(self) -> None:
        """End the bar's line on a terminal, so that what follows starts a line of its own."""
        if self.tty:
            try:
                self.stream.write("\n")
                self.stream.flush()
            except OSError:
                pass


def cmd_compare(args) -> int:
    """``neuvision compare CONFIG...``: run each condition over seeds and compare them; 2
    when a run failed."""
    from lab.compare import CompareError, compare

    overrides = list(args.set or [])
    if args.duration_s is not None:
        overrides.append(f"experiment.duration_s={args.duration_s}")
    try:  # every condition's file, params, seeds, jobs, names and --out: before any run
        result = compare(args.configs, args.seeds, args.out, args.jobs, overrides)
    except CompareError as exc:
        raise InputError(str(exc)) from None
    failed = [r for r in result["runs"] if not r["ok"]]
    return EXIT_FAULT if failed else EXIT_OK


def cmd_analyze(args) -> int:
    """``neuvision analyze RUN_DIR``: analyse a recorded run (metrics, figures, report)
    and print its metrics as JSON; an unfinished or running run is noted on stderr."""
    from hub.analysis.spikes import AnalysisInputError
    from hub.record import UNFINISHED, read_manifest
    from lab.run_analysis import ANALYSIS_DIR, analyze_run

    run_dir = _recorded_run(args.run_dir, "analyse")
    if args.out is not None:
        out = make_output_folder(args.out, "--out")
    else:
        out = make_output_folder(run_dir / ANALYSIS_DIR, "the run folder (--out writes elsewhere)")
    manifest = read_manifest(run_dir)  # its outcome as read back
    if not manifest:
        print(
            f"neuvision: note: {run_dir} has no manifest.json: its settings are unknown, so "
            "the paper's analysis parameters are used and the run's outcome is not known",
            file=sys.stderr,
        )
    elif manifest.get("outcome") == UNFINISHED:
        print(f"neuvision: note: {run_dir} is unfinished: {manifest['reason']}", file=sys.stderr)
    elif manifest.get("outcome") == "running":
        print(
            f"neuvision: note: {run_dir} is still running: this analyses what it has "
            "recorded so far",
            file=sys.stderr,
        )
    try:
        # stages said at a terminal: a long record takes a while (its errors stay one line)
        interactive = sys.stderr.isatty()
        metrics = analyze_run(run_dir, args.out, progress=_stage_printer() if interactive else None)
    except AnalysisInputError as exc:
        raise InputError(f"cannot analyse {run_dir}: {exc}") from None
    except OSError as exc:  # a full disk: what was written before is whole (write_whole)
        raise OutputError(f"cannot write the analysis in {out}: {exc.strerror or exc}") from None
    for note in ("record_short", "record_damaged"):
        if note in metrics["metrics"]:
            print(f"neuvision: note: {metrics['metrics'][note]}", file=sys.stderr)
    _emit(json.dumps(metrics, indent=2, default=str))
    return EXIT_OK


def _stage_printer():
    """``say(stage)``: the stage and the seconds since the first, on stderr."""
    start = time.monotonic()

    def say(stage: str) -> None:
        print(f"neuvision: {stage} ({time.monotonic() - start:.1f} s)", file=sys.stderr)

    return say


def cmd_reproduce(args) -> int:
    """``neuvision reproduce``: the paper's validation of the simulated culture, for one
    seed or several (``--seeds``), in ``--out`` or a new folder under ``runs``."""
    from hub.record import new_run_dir
    from lab.reproduce import DEFAULT_CULTURE, reproduce, reproduce_seeds
    from lab.seeds import parse_seeds

    seeds = None
    if args.seeds:
        try:
            seeds = parse_seeds(args.seeds)
        except ValueError as exc:
            raise InputError(str(exc)) from None
    culture = args.culture or DEFAULT_CULTURE
    if args.out:
        out = make_output_folder(args.out, "--out")
    else:
        out = new_run_dir("runs", "reproduce", what="runs")
    if seeds:
        reproduce_seeds(out, seeds, quick=args.quick, jobs=args.jobs, config_path=culture)
    else:
        reproduce(out, quick=args.quick, seed=args.seed, config_path=culture)
    print(f"neuvision: reproduction in {out}", file=sys.stderr)
    return EXIT_OK


def cmd_export(args) -> int:
    """``neuvision export RUN_DIR --nwb FILE``: write a recorded run as an NWB file
    (replacing one there)."""
    from lab.experiment import Run
    from lab.export_nwb import ExportError, export_nwb

    run_dir = _recorded_run(args.run_dir, "export")
    if args.nwb.is_dir():
        raise InputError(f"--nwb: {args.nwb} is a folder; give the file to write")
    make_output_folder(args.nwb.parent, "--nwb")
    replaced = args.nwb.exists()
    try:
        run = Run.open(run_dir)
    except FileNotFoundError as exc:  # a record without its manifest: no metadata to write
        raise InputError(f"{exc}: an NWB file needs the run's metadata") from None
    try:
        path = export_nwb(run, args.nwb)
    except ExportError as exc:
        raise InputError(str(exc)) from None
    for note in (run.record.short_note(), run.record.damage_note()):
        if note:
            print(f"neuvision: note: {note}", file=sys.stderr)
    replaced = " (it replaced the file there)" if replaced else ""
    print(f"neuvision: {run_dir} written to {path}{replaced}", file=sys.stderr)
    return EXIT_OK


# each emulator's own options (the other's refused, not ignored)
_KHEPERA_ONLY = ("world", "dialect", "ir_table", "baud", "stop_bits", "link", "garbage_every",
                 "drop_every")  # fmt: skip
_INTAN_ONLY = ("culture", "command_port", "spike_port", "realtime_priority")


def cmd_emulate(args) -> int:
    """``neuvision emulate khepera|intan``: serve an emulated device until signalled;
    the other device's options are refused."""
    from adapters.khepera.calibration import IRCalibration
    from adapters.khepera.emulator import KheperaEmulator, run_until_signalled
    from adapters.khepera.link import BAUDS
    from devices.khepera import MODELS

    others = _INTAN_ONLY if args.device == "khepera" else _KHEPERA_ONLY
    given = [f"--{name.replace('_', '-')}" for name in others if getattr(args, name) is not None]
    if given:
        raise InputError(
            f"{', '.join(given)}: not an option of the {args.device} emulator "
            "(neuvision emulate --help)"
        )
    if args.device == "intan":
        from adapters.mea.emulator import DEFAULT_CULTURE, IntanEmulator, run_until_signalled

        args.command_port = 5000 if args.command_port is None else args.command_port
        args.spike_port = 5002 if args.spike_port is None else args.spike_port
        if args.realtime_priority is None:
            args.realtime_priority = EMULATOR_PRIORITY

        for option, port in (
            ("--command-port", args.command_port),
            ("--spike-port", args.spike_port),
        ):
            if not 1 <= port <= 65535:
                raise InputError(f"{option} must be a TCP port, 1 to 65535, got {port}")
        if not 0 <= args.realtime_priority <= 99:
            raise InputError(
                f"--realtime-priority must be 0 (ordinary scheduling) to 99, got "
                f"{args.realtime_priority}"
            )
        try:
            emulator = IntanEmulator(
                args.culture or DEFAULT_CULTURE,
                seed=1 if args.seed is None else args.seed,
                command_port=args.command_port,
                spike_port=args.spike_port,
                realtime_priority=args.realtime_priority,
            )
        except OSError as exc:  # a port taken: another emulator, or RHX itself
            raise InputError(
                f"cannot listen on 127.0.0.1:{args.command_port}/{args.spike_port}: "
                f"{exc.strerror or exc}"
            ) from None
        run_until_signalled(emulator)
        return EXIT_OK
    args.dialect = args.dialect or "khepera2"
    args.garbage_every, args.drop_every = args.garbage_every or 0, args.drop_every or 0
    if args.link:
        _check_link(Path(args.link))
    if args.baud is not None and args.baud not in BAUDS:
        raise InputError(f"--baud must be one of {BAUDS}, got {args.baud}")
    for option, every in (("--garbage-every", args.garbage_every),
                          ("--drop-every", args.drop_every)):  # fmt: skip
        if every < 0:
            raise InputError(f"{option} must be >= 0, got {every} (0: never)")
    model = MODELS[args.dialect]
    if model.ir_table is None and args.ir_table is None:
        raise InputError(
            f"--ir-table: a {model.name} has no published IR response; give a table (CSV "
            "distance_m,value), as its adapter needs one (docs/khepera.md)"
        )
    table = IRCalibration.from_file(args.ir_table, "--ir-table").table if args.ir_table else None
    emulator = KheperaEmulator(  # a bad world file: a config error naming the key
        args.world,
        dialect=args.dialect,
        ir_table=table,
        baud=args.baud,
        stop_bits=args.stop_bits,
        seed=args.seed or 0,
    )
    emulator.faults.garbage_every, emulator.faults.drop_every = args.garbage_every, args.drop_every
    run_until_signalled(emulator, link=args.link)
    return EXIT_OK


def _check_link(link: Path) -> None:
    """``emulate khepera --link``: InputError unless a symlink can be made there (a folder
    that exists; nothing there but, at most, an old link, which is replaced)."""
    if link.is_symlink():
        return
    if link.exists():
        kind = "a folder" if link.is_dir() else "a file"
        raise InputError(f"--link: {link} is {kind}, not a link; give a path with nothing there")
    if not link.parent.is_dir():
        raise InputError(f"--link: {link.parent} is not a folder (the link's folder must exist)")
    if not os.access(link.parent, os.W_OK | os.X_OK):
        raise InputError(f"--link: cannot write in {link.parent}: permission denied")


def cmd_certs(args) -> int:
    """``neuvision certs DIR``: make the certificate authority, each role's certificate
    and, with ``--passwords``, their passwords; the files written, one a line on stdout."""
    try:
        from hub.certs import MAX_DAYS, CertsError, make_certificates, make_passwords
    except ImportError:
        raise InputError(
            "neuvision certs needs the 'cryptography' package: pip install 'neuvision[security]'"
        ) from None
    hosts = [h.strip() for h in args.hub_hosts.split(",")] if args.hub_hosts else None
    if not 1 <= args.days <= MAX_DAYS:
        raise InputError(f"--days must be 1 to {MAX_DAYS}, got {args.days}")
    if Path(args.dir).exists() and not Path(args.dir).is_dir():
        raise InputError(f"{args.dir} is not a folder: give the folder to write the files in")
    roles = [r.strip() for r in args.roles.split(",")]
    try:
        written = make_certificates(args.dir, roles, hub_hosts=hosts, days=args.days)
        if args.passwords:
            written += make_passwords(args.dir, roles)
    except CertsError as exc:
        raise InputError(str(exc)) from None
    except ValueError as exc:
        raise InputError(f"--roles / --hub-hosts: {exc}") from None
    except OSError as exc:
        raise InputError(f"cannot write in {args.dir}: {exc.strerror or exc}") from None
    for path in written:
        _emit(str(path))
    print(f"neuvision: {len(written)} files in {args.dir}", file=sys.stderr)
    return EXIT_OK


def cmd_dashboard(args) -> int:
    """``neuvision dashboard [CONFIG]``: serve the live dashboard (following the session's
    hub on this machine when no address is given), or ``--replay`` a recorded run; 2 when
    it cannot serve."""
    try:
        from dashboard.app import run_dashboard
        from dashboard.replay import ReplayError
        from dashboard.server import ServeError
    except ImportError as exc:
        raise InputError(
            f"the dashboard needs its web server: pip install 'neuvision[dashboard]' ({exc})"
        ) from None
    if args.replay and (args.connect or args.session):
        raise InputError(
            "--replay plays a recorded run folder; --connect and --session watch a live hub: "
            "give one or the other"
        )
    replay = _run_folder(args.replay) if args.replay else None
    if replay is not None:
        _readable_run(replay)
    # through the config, whose checks name the key: dashboard.port must be <= 65535, ...
    for flag, key in (("port", "dashboard.port"), ("host", "dashboard.host")):
        if getattr(args, flag) is not None:
            args.set = [*(args.set or []), f"{key}={json.dumps(getattr(args, flag))}"]
    given = load_config(args.config, _overrides(args))
    # no address given: follow the session's hub on this machine from run to run
    follow = not replay and not given.bus.connect
    cfg, not_found = (given, "") if replay else _hub_config(args)
    if not_found and follow:
        print(
            f"neuvision: no hub yet{not_found}: the dashboard waits, and follows the "
            "session's next run on this machine",
            file=sys.stderr,
        )
    try:
        run_dashboard(
            cfg,
            replay=replay,
            follow_local=follow,
            speed=args.speed,
            announce=lambda line: print(f"neuvision: {line}", file=sys.stderr, flush=True),
        )
    except ReplayError as exc:
        raise InputError(str(exc)) from None
    except ServeError as exc:
        if exc.bad_address:
            raise InputError(_one_line(exc)) from None
        print(f"neuvision: {_one_line(exc)}", file=sys.stderr)
        return EXIT_FAULT
    return EXIT_OK


def _hub_config(args):
    """The config of a command that reaches a running hub (``ctl``, ``dashboard``), and
    what to add to a message that none answered. With no address given (``--connect``,
    ``bus.connect``), a hub of the session running on this machine is found where
    ``neuvision run`` says it listens (:mod:`hub.local_hubs`)."""
    from hub import local_hubs

    cfg = load_config(args.config, _overrides(args))
    if cfg.bus.connect:
        return cfg, ""
    try:
        found = local_hubs.find(cfg.bus.session)
    except local_hubs.AmbiguousSession as exc:
        raise InputError(str(exc)) from None
    if found is None:
        return cfg, (
            f" (no hub on this machine (neuvision run or hub) runs session {cfg.bus.session!r}; "
            "for a hub elsewhere give --connect HOST[:PORT])"
        )
    print(
        f"neuvision: the hub of session {cfg.bus.session!r} on this machine listens on "
        f"{', '.join(found.locators)} (run folder {found.run_dir})",
        file=sys.stderr,
    )
    connect = f"bus.connect={json.dumps(list(found.locators))}"
    return load_config(args.config, [*_overrides(args), connect]), ""


def cmd_ctl(args) -> int:
    """``neuvision ctl CMD``: send a control command to a running hub and print its reply
    as JSON; 0 when the hub took it, 2 when it refused it or none answered."""
    from hub.ctl import ctl

    cfg, not_found = _hub_config(args)
    try:
        reply = ctl(cfg.bus, args.cmd, timeout_s=args.timeout_s, timeout_name="--timeout-s")
    except BusError as exc:
        raise BusError(f"{exc}{not_found}") from None
    if reply is None:
        where = ", ".join(cfg.bus.connect or cfg.bus.listen)
        print(f"neuvision: no hub answered on session {cfg.bus.session!r} at {where}{not_found}",
              file=sys.stderr)  # fmt: skip
        return EXIT_FAULT
    out = {"ok": reply.ok, "state": reply.state, "reason": reply.reason, "data": reply.data}
    _emit(json.dumps(out, indent=2, default=str))
    return EXIT_OK if reply.ok else EXIT_FAULT


COMMANDS = {
    "certs": cmd_certs,
    "run": cmd_run,
    "hub": cmd_hub,
    "endpoint": cmd_endpoint,
    "observe": cmd_observe,
    "record-info": cmd_record_info,
    "compare": cmd_compare,
    "analyze": cmd_analyze,
    "reproduce": cmd_reproduce,
    "emulate": cmd_emulate,
    "export": cmd_export,
    "dashboard": cmd_dashboard,
    "ctl": cmd_ctl,
}

if __name__ == "__main__":
    sys.exit(main())
