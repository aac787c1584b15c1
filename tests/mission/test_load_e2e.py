"""A loaded machine does not end the mission (issue 21): a real 3-drone `swarm run` in the box world, during
which the test keeps both cores busy for 3 s with busy-loop processes of its own at normal priority, completes
with no failsafe. `swarm run` raises the simulator's and the agents' scheduling priority (`mission.sim_nice`,
`mission.agent_nice`), and the agents count only the telemetry silence they were awake to hear."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from swarm.bus.phase import Phase
from swarm.config import load_config
from swarm.mission.run import RunState, run_mission
from tests.helpers import SwarmPorts, kill_all, log_events, processes_mentioning

pytestmark = [pytest.mark.timeout(300), pytest.mark.mission, pytest.mark.alone]  # it loads both cores

LOAD_S = 3.0
LOAD_AFTER_FLYING_S = 1.0  # every agent has been in its FLYING phase this long when the load starts
# (the box is explored within about 10 s of that, so a later load would race the end of the mission)
BUSY_LOOP = (
    "import sys, time\n"
    "end = time.monotonic() + float(sys.argv[1])\n"
    "while time.monotonic() < end:\n"
    "    pass\n"
    "print(time.process_time())\n"
)


def _cpu_jiffies() -> tuple[int, int]:
    """(busy, total) jiffies of every core since boot, from /proc/stat (idle and iowait are not busy)."""
    fields = [int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    idle = fields[3] + fields[4]
    return sum(fields) - idle, sum(fields)


@dataclass
class Load:
    """Busy loops started once every agent has logged its FLYING phase LOAD_AFTER_FLYING_S ago, two per core,
    each for LOAD_S."""

    logs: Path
    drones: int
    per_core: int = 2
    procs: list[subprocess.Popen[str]] = field(default_factory=list)
    all_flying_at: float | None = None
    started_wall: float | None = None
    ended_wall: float | None = None
    jiffies: list[tuple[int, int]] = field(default_factory=list)
    cpu_s: list[float] = field(default_factory=list)

    def __call__(self, state: RunState) -> None:
        now = time.monotonic()
        if self.all_flying_at is None:
            if all(self._flying(i) for i in range(1, self.drones + 1)):
                self.all_flying_at = now
        elif not self.procs and now - self.all_flying_at >= LOAD_AFTER_FLYING_S:
            self.jiffies.append(_cpu_jiffies())
            self.started_wall = time.time()
            self.procs = [
                subprocess.Popen([sys.executable, "-c", BUSY_LOOP, str(LOAD_S)], stdout=subprocess.PIPE, text=True)
                for _ in range(self.per_core * (os.cpu_count() or 1))
            ]
        elif self.procs and self.ended_wall is None and all(p.poll() is not None for p in self.procs):
            self.ended_wall = time.time()
            self.jiffies.append(_cpu_jiffies())
            self.cpu_s = [float(p.stdout.read()) for p in self.procs if p.stdout is not None]

    def _flying(self, agent_id: int) -> bool:
        log = self.logs / f"agent-{agent_id}.log"
        return log.exists() and any(e.get("phase") == Phase.FLYING for e in log_events(log))

    @property
    def busy_fraction(self) -> float:
        (busy_0, total_0), (busy_1, total_1) = self.jiffies
        return (busy_1 - busy_0) / max(1, total_1 - total_0)


def mission_under_load(
    out: Path, ports: SwarmPorts, per_core: int = 2, **overrides: Any
) -> tuple[dict[str, Any], Load]:
    config = load_config(
        overrides={
            "mission.world": "box",
            "mission.out": str(out),
            "mission.drones": 3,
            "mission.max_time_s": 240.0,
            **ports.settings(),
            **overrides,
        }
    )
    load = Load(out / "logs", config.mission.drones, per_core)
    try:
        report = run_mission(config, live=False, on_tick=load)
    finally:
        kill_all(load.procs)
    return report, load


def test_a_3_s_load_of_both_cores_in_mid_flight_neither_stalls_the_swarm_nor_lands_it(
    tmp_path: Path, swarm_ports: SwarmPorts
) -> None:
    out = tmp_path / "run"
    report, load = mission_under_load(out, swarm_ports)

    assert load.started_wall is not None and load.ended_wall is not None, "the load never ran"
    print(
        f"load {load.ended_wall - load.started_wall:.2f} s, cores busy {load.busy_fraction:.1%}, load CPU "
        f"{sum(load.cpu_s):.2f} s, sim stalls {report['sim_stalls']}, priority {report['priority']}"
    )
    assert load.ended_wall - load.started_wall >= LOAD_S
    # the window opens before the loops start and closes when a supervision tick (every 0.25 s) sees them gone
    assert load.busy_fraction > 0.9, f"the cores were not fully loaded: {load.busy_fraction:.1%} busy"
    assert report["priority"]["granted"], report["priority"]
    assert report["status"] == "complete", report["reason"]
    assert report["explored_fraction"] >= 0.9
    for agent in report["agents"]:
        assert agent["exit_code"] == 0 and agent["landed"], agent
        events = log_events(out / "logs" / f"agent-{agent['id']}.log")
        assert not [e for e in events if e["event"].startswith("failsafe")], f"agent {agent['id']} failed safe"
        # the load came in the middle of every drone's flight: after it was flying, before it began to land
        [flying] = [e["t"] for e in events if e.get("phase") == Phase.FLYING]
        landing = [e["t"] for e in events if e.get("phase") == Phase.LANDING]
        assert flying < load.started_wall and landing and load.ended_wall < landing[0], (flying, landing)
    assert all(stall["s"] < 1.5 for stall in report["sim_stalls"]), report["sim_stalls"]
    assert not processes_mentioning(str(out)), "swarm run left processes behind"
