"""Start, watch and stop `swarm mapnode` processes on loopback or in network namespaces (tests and benchmarks).

Each node listens on ``tcp/<host>:<base + id>`` and dials the nodes given (default: every lower id, a full mesh).
Status files are polled; nothing here sleeps to hide a race: `wait_for` polls a condition until a deadline.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from swarm.config import Vec3
from swarm.files import read_model
from swarm.mission.files import MapNodeStatus
from swarm.mission.ports import find_free_base
from swarm.mission.processes import swarm_command


@dataclass
class NodeSpec:
    id: int
    patches: int = 3
    period_s: float = 0.3
    delay_s: float = 0.0
    position: Vec3 | None = None
    connect: list[int] | None = None  # node ids to dial (default: every lower id)
    listen: str | None = None  # listen host (default 127.0.0.1)
    extra: list[str] = field(default_factory=list)  # more --set overrides


class NodeSwarm:
    """Start, watch and stop mapnode processes; every process is killed at `close`, even after a failure."""

    def __init__(self, tmp: Path, mission: str = "synctest", mode: str = "peer", sets: list[str] | None = None) -> None:
        self.tmp = tmp
        self.sets = list(sets or [])
        self.mission = mission
        self.mode = mode
        self.base = find_free_base("127.0.0.1", 64, "tcp", 30000 + (os.getpid() * 37) % 20000)
        self.procs: dict[int, subprocess.Popen[bytes]] = {}
        self.hosts: dict[int, str] = {}

    def endpoint(self, node_id: int) -> str:
        return f"tcp/{self.hosts.get(node_id, '127.0.0.1')}:{self.base + node_id}"

    def status_path(self, node_id: int) -> Path:
        return self.tmp / f"node-{node_id}.json"

    def start(self, spec: NodeSpec, wrap: Callable[[list[str]], list[str]] | None = None) -> None:
        host = spec.listen or "127.0.0.1"
        self.hosts[spec.id] = host
        connect = spec.connect if spec.connect is not None else [k for k in sorted(self.hosts) if k < spec.id]
        sets = [
            *self.sets,
            f"mission.name={self.mission}",
            f"bus.mode={self.mode}",
            f'bus.listen=["tcp/{host}:{self.base + spec.id}"]',
            "bus.connect=[" + ",".join(f'"{self.endpoint(k)}"' for k in connect) + "]",
            *spec.extra,
        ]
        argv = swarm_command(
            "mapnode",
            "--id",
            str(spec.id),
            "--status",
            str(self.status_path(spec.id)),
            "--patches",
            str(spec.patches),
            "--period",
            str(spec.period_s),
            "--delay",
            str(spec.delay_s),
        )
        if spec.position is not None:
            argv += ["--position", ",".join(str(c) for c in spec.position)]
        for item in sets:
            argv += ["--set", item]
        if wrap is not None:
            argv = wrap(argv)
        log = open(self.tmp / f"node-{spec.id}.log", "wb")
        self.procs[spec.id] = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT)

    def status(self, node_id: int) -> dict[str, Any]:
        """Node K's status as JSON data, {} before it first wrote one; FileFormatError when it is invalid."""
        try:
            return read_model(self.status_path(node_id), MapNodeStatus).model_dump(mode="json")
        except FileNotFoundError:
            return {}

    def statuses(self) -> dict[int, dict[str, Any]]:
        return {k: self.status(k) for k in self.procs}

    def wait_for(self, condition: Callable[[dict[int, dict[str, Any]]], bool], timeout_s: float, what: str) -> float:
        """Poll the status files until `condition` holds; the seconds it took. Fails with the last statuses."""
        start = time.monotonic()
        while time.monotonic() - start < timeout_s:
            for k, proc in self.procs.items():
                if proc.poll() is not None:
                    raise AssertionError(f"node {k} exited with {proc.returncode}: {self.log_tail(k)}")
            if condition(self.statuses()):
                return time.monotonic() - start
            time.sleep(0.1)
        summary = {k: (len(s.get("held", [])), s.get("sync", {}).get("rejected")) for k, s in self.statuses().items()}
        raise AssertionError(f"not within {timeout_s} s: {what}; held per node: {summary}")

    def sealed(self, node_id: int) -> set[str]:
        return {entry["id"] for entry in self.status(node_id).get("sealed", [])}

    def all_sealed(self) -> set[str]:
        return set().union(*(self.sealed(k) for k in self.procs))

    def log_tail(self, node_id: int) -> str:
        try:
            return (self.tmp / f"node-{node_id}.log").read_text()[-2000:]
        except OSError:
            return ""

    def close(self) -> None:
        for k in list(self.procs):
            if self.procs[k].poll() is None:
                self.procs[k].send_signal(signal.SIGTERM)
        deadline = time.monotonic() + 10
        for proc in self.procs.values():
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def holds_all(expected: set[str], ids: list[int] | None = None) -> Callable[[dict[int, dict[str, Any]]], bool]:
    def condition(statuses: dict[int, dict[str, Any]]) -> bool:
        chosen = statuses if ids is None else {k: statuses.get(k, {}) for k in ids}
        return all(set(s.get("held", [])) == expected for s in chosen.values())

    return condition
