"""A battery that cannot last the mission (issue 24): a real 3-drone `swarm run` in the box world in which drone 3
takes off with 26 % left on a battery that hovers 10 minutes when full, so it falls below
agent.battery_home_fraction (25 %) some 6 s into the flight. It must go home and land there, and the other two
must finish the map; PX4's own battery failsafe never has to act."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from swarm.config import load_config
from swarm.mission.report import read_sim_status
from swarm.mission.run import run_mission
from tests.helpers import SwarmPorts, log_events, processes_mentioning

pytestmark = [pytest.mark.timeout(300), pytest.mark.mission]


def test_a_drone_whose_battery_runs_low_lands_at_home_and_the_others_complete_the_map(
    tmp_path: Path, swarm_ports: SwarmPorts
) -> None:
    out = tmp_path / "run"
    config = load_config(
        overrides={
            "mission.world": "box",
            "mission.out": str(out),
            "mission.drones": 3,
            "mission.max_time_s": 240.0,
            "sim.battery_minutes": 10.0,
            "sim.battery_starts": {"3": 0.26},
            **swarm_ports.settings(),
        }
    )
    report = run_mission(config, live=False)
    assert report["status"] == "complete", report["reason"]
    assert report["explored_fraction"] >= 0.95
    assert report["collisions"] == 0, report["collision_events"]
    events = log_events(out / "logs" / "agent-3.log")
    [low] = [e for e in events if e["event"] == "battery_low"]
    assert low["airborne"] and low["fraction"] < 0.25, low
    sim = read_sim_status(out)
    assert sim is not None
    vehicle = {v.id: v for v in sim.vehicles}[3]
    # home, within a planning cell and the waypoint tolerance (the spawn points are 1.5 m apart)
    assert vehicle.landed_and_disarmed and math.dist(vehicle.position[:2], vehicle.home[:2]) < 0.75, vehicle
    assert vehicle.battery > 0.15  # above PX4's BAT_LOW_THR: its failsafe had nothing to do
    texts = [e["text"] for e in events if e["event"] == "statustext"]
    assert not [t for t in texts if "battery" in t.lower() or t.startswith("Failsafe")], texts
    agents = {a["id"]: a for a in report["agents"]}
    assert agents[3]["landed"] and agents[3]["exit_code"] == 0, agents[3]
    for k in (1, 2):
        summary = json.loads((out / "agents" / f"agent-{k}.json").read_text())
        assert summary["exploration_done"], summary["exploration_done_reason"]
        assert agents[k]["landed"] and agents[k]["exit_code"] == 0, agents[k]
    assert not processes_mentioning(str(out)), "swarm run left processes behind"
