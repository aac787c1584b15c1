"""Test helpers: free port ranges (tests run beside other swarms on the same machine) and process hygiene."""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import psutil
import zenoh

from swarm.errors import PortInUseError
from swarm.mission.ports import SENSOR_PORT_OFFSET, ensure_free, find_free_base


@dataclass(frozen=True)
class SwarmPorts:
    vehicle_base: int
    gcs_base: int
    bus_base: int

    def settings(self) -> dict[str, int | bool]:
        """The three port bases as `load_config` overrides, and no run recording: it costs a mission about 5 % of
        a core and its end some seconds, and only the tests of the recording ask for it (mission.rrd = true)."""
        return {
            "sim.vehicle_base_port": self.vehicle_base,
            "sim.gcs_base_port": self.gcs_base,
            "bus.base_port": self.bus_base,
            "mission.rrd": False,
        }

    def overrides(self) -> list[str]:
        """`settings` as `--set` options."""
        return [item for key, value in self.settings().items() for item in ("--set", f"{key}={str(value).lower()}")]


EPHEMERAL_PORTS_FROM = 32768  # Linux's default ip_local_port_range starts here: outgoing connections take these


PORTS_FROM = 20000  # test ports start here, clear of the defaults (14540, 14580, 7447)


def worker_ports() -> tuple[int, int]:
    """This pytest-xdist worker's share [lo, hi) of the test ports (PORTS_FROM up to the ephemeral range). A port
    is found free when a test starts and bound later: with both workers choosing from one range, a simulator
    found its port taken by the other worker's test ("UDP port 29800 (vehicle 1) is already in use")."""
    count = max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")[2:]
    index = int(worker) % count if worker.isdigit() else 0
    span = (EPHEMERAL_PORTS_FROM - PORTS_FROM) // count
    return PORTS_FROM + index * span, PORTS_FROM + (index + 1) * span


def free_swarm_ports() -> SwarmPorts:
    """Bases for a test mission's ports, below the ephemeral range: a port found free there can be taken by any
    outgoing connection before the mission binds it. The sensor router (bus base + SENSOR_PORT_OFFSET) is checked
    too."""
    while True:
        lo, hi = worker_ports()
        start = random.randrange(lo, hi - 300 - SENSOR_PORT_OFFSET, 100)
        stop = hi - SENSOR_PORT_OFFSET - 20
        vehicle = find_free_base("127.0.0.1", 16, "udp", start, stop)
        gcs = find_free_base("127.0.0.1", 16, "udp", vehicle + 20, stop)
        bus = find_free_base("127.0.0.1", 17, "tcp", gcs + 20, stop)
        try:
            ensure_free("127.0.0.1", bus + SENSOR_PORT_OFFSET, "tcp", "sensor streams")
        except PortInUseError:
            continue
        return SwarmPorts(vehicle, gcs, bus)


def swarm_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "swarm", *args]


def processes_mentioning(needle: str) -> list[psutil.Process]:
    """Live processes whose command line contains `needle` (a unique temp path), other than pytest itself."""
    found = []
    for proc in psutil.process_iter(["cmdline", "status"]):
        try:
            cmdline = " ".join(proc.info["cmdline"] or [])
        except psutil.Error:
            continue
        if needle in cmdline and proc.info["status"] != psutil.STATUS_ZOMBIE:
            found.append(proc)
    return found


def kill_all(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            p.kill()
    for p in procs:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            pass


def log_events(log: Path) -> list[dict[str, Any]]:
    """The JSON events of an agent's log (one per line; other lines skipped)."""
    events = []
    for line in log.read_text(errors="replace").splitlines():
        if line.startswith("{"):
            try:
                events.append(json.loads(line))
            except ValueError:
                continue
    return events


@contextmanager
def loopback_zenoh(mode: str) -> Iterator[tuple[zenoh.Session, str]]:
    """A Zenoh session in `mode` ("peer" or "router") listening on a free loopback port: (session, endpoint)."""
    port = find_free_base("127.0.0.1", 1, "tcp", random.randrange(30000, 50000))
    endpoint = f"tcp/127.0.0.1:{port}"
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("listen/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(config)
    try:
        yield session, endpoint
    finally:
        session.close()
