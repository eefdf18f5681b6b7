"""Hosts as Linux network namespaces: each endpoint on a "host" of its own, joined to the
hub's (the test process's namespace) by a veth pair. Needs root and ``ip``; callers skip
with :data:`UNAVAILABLE` as the reason otherwise. Used by the tests and ``bench/remote.py``.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import subprocess
import sys
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from hub.bus import free_tcp_port
from hub.config import load_config
from hub.launch import die_with_parent
from hub.loop import Hub
from hub.record import read_run


def _why_unavailable() -> str:
    if sys.platform != "linux":
        return "network namespaces are Linux only"
    if os.geteuid() != 0:
        return "network namespaces need root"
    if shutil.which("ip") is None:
        return "no 'ip' command (iproute2)"
    return ""


def _probe() -> str:
    """ "" if a namespace can be made here, else why not (a container without the right)."""
    why = _why_unavailable()
    if why:
        return why
    name = f"nvprobe{os.getpid()}"
    done = subprocess.run(["ip", "netns", "add", name], capture_output=True, text=True)
    if done.returncode != 0:
        return f"cannot make a network namespace: {done.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", name], capture_output=True)
    return ""


#: why hosts cannot be made here ("" when they can)
UNAVAILABLE = _probe()


@dataclass(frozen=True)
class Host:
    """One namespace: its name, the hub's address on its link, its own address."""

    namespace: str
    hub_ip: str
    ip: str
    link: str  # the hub side of the veth pair (for tc)

    def command(self, argv: list[str]) -> list[str]:
        """``argv`` run inside this host's namespace."""
        return ["ip", "netns", "exec", self.namespace, *argv]


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


@contextmanager
def hosts(names: list[str]):
    """Make one namespace per name, each linked to this one; remove them at the end.

    Yields ``{name: Host}``. Raises ``subprocess.CalledProcessError`` if the kernel refuses.
    """
    tag = secrets.token_hex(2)
    made: dict[str, Host] = {}
    try:
        for n, name in enumerate(names, start=1):
            subnet = f"10.{200 + n}.{int(tag, 16) % 250}"
            host = Host(f"nv{tag}-{name}", f"{subnet}.1", f"{subnet}.2", f"nv{tag}{n}a")
            _ip("netns", "add", host.namespace)
            made[name] = host
            _ip("link", "add", host.link, "type", "veth", "peer", "name", f"nv{tag}{n}b")
            _ip("link", "set", f"nv{tag}{n}b", "netns", host.namespace)
            _ip("addr", "add", f"{host.hub_ip}/24", "dev", host.link)
            _ip("link", "set", host.link, "up")
            inside = ["netns", "exec", host.namespace, "ip"]
            _ip(*inside, "addr", "add", f"{host.ip}/24", "dev", f"nv{tag}{n}b")
            _ip(*inside, "link", "set", f"nv{tag}{n}b", "up")
            _ip(*inside, "link", "set", "lo", "up")
        yield made
    finally:
        for host in made.values():
            subprocess.run(["ip", "link", "del", host.link], capture_output=True)
            subprocess.run(["ip", "netns", "del", host.namespace], capture_output=True)


def netem_available() -> str:
    """ "" if ``tc netem`` works on this kernel, else why not."""
    if shutil.which("tc") is None:
        return "no 'tc' command"
    if UNAVAILABLE:
        return UNAVAILABLE
    with hosts(["probe"]) as made:
        link = made["probe"].link
        done = subprocess.run(
            ["tc", "qdisc", "add", "dev", link, "root", "netem", "delay", "5ms"],
            capture_output=True,
            text=True,
        )
    return "" if done.returncode == 0 else f"tc netem unavailable: {done.stderr.strip()}"


ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = str(ROOT / "configs" / "closed_loop.toml")


def run_hub(cfg, run_dir: Path, procs: list[subprocess.Popen]):
    """Run the hub of ``cfg`` into ``run_dir``, then wait for its endpoints' processes to
    end (killed after 30 s); returns the hub's result."""
    try:
        return Hub(cfg, run_dir=run_dir).run()
    finally:
        for p in procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def closed_loop(tmp_path: Path, name: str, places: dict | None, *extra: str):
    """1 s of the paper's closed loop in lockstep, seed 3 (``extra`` overrides after), each
    endpoint on this host (``places`` None) or on its host of ``places``; returns the run's
    record and result."""
    port = free_tcp_port()
    session = f"test-{secrets.token_hex(4)}"
    listen = [f"tcp/{h.hub_ip}:{port}" for h in places.values()] if places else None
    common = [
        "experiment.duration_s=1",
        "experiment.seed=3",
        'loop.mode="lockstep"',
        f"bus.session={json.dumps(session)}",
        f"bus.listen={json.dumps(listen or [f'tcp/127.0.0.1:{port}'])}",
        'body.launch="external"',
        'culture.launch="external"',
        *extra,
    ]
    cfg = load_config(EXPERIMENT, common)
    procs = []
    for role in ("body", "culture"):
        where = places[role] if places else None
        connect = f"tcp/{where.hub_ip if where else '127.0.0.1'}:{port}"
        argv = [sys.executable, "-m", "hub.cli", "endpoint", role, EXPERIMENT, "--once"]
        for item in common + [f"bus.connect={json.dumps([connect])}"]:
            argv += ["--set", item]
        log = open(tmp_path / f"{name}-{role}.log", "wb")
        procs.append(
            subprocess.Popen(
                where.command(argv) if where else argv,
                stdout=log,
                stderr=subprocess.STDOUT,
                preexec_fn=die_with_parent,
                cwd=ROOT,
            )
        )
    run_dir = tmp_path / name
    run_dir.mkdir()
    result = run_hub(cfg, run_dir, procs)
    if result.outcome != "completed":
        raise RuntimeError(f"the closed loop across hosts did not complete: {result.reason}")
    return read_run(run_dir), result
