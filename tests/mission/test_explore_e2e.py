"""Exploration end to end (issue 5): real `swarm run` missions in the small box world, one per capability.

Real processes throughout: the simulator, one agent per drone (MAVSDK over UDP, Open3D mapping, Zenoh on
loopback), the observer. Assertions come from the simulator's truth, the observer and the agents' own logs."""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path
from typing import Any

import pytest

from swarm.config import load_config
from swarm.mission.report import read_json
from swarm.mission.run import RunState, run_mission
from tests.helpers import SwarmPorts, log_events, processes_mentioning

pytestmark = pytest.mark.timeout(300)


def _config(out: Path, ports: SwarmPorts, **overrides: Any):
    return load_config(overrides={
        "mission.world": "box", "mission.out": str(out), "sim.vehicle_base_port": ports.vehicle_base,
        "sim.gcs_base_port": ports.gcs_base, "bus.base_port": ports.bus_base, **overrides,
    })


def test_killing_the_leader_hands_over_within_3_s_and_the_others_finish(tmp_path: Path, swarm_ports: SwarmPorts) -> None:
    out = tmp_path / "run"
    config = _config(out, swarm_ports, **{"mission.drones": 3, "mission.max_time_s": 240.0})
    killed: dict[str, float] = {}

    def kill_the_leader_mid_mission(state: RunState) -> None:
        observer = read_json(out / "observer.json") or {}
        if not killed and observer.get("explored_fraction", 0.0) > 0.3:
            killed["t"] = time.time()
            state.agents[1].signal(signal.SIGKILL)

    report = run_mission(config, live=False, on_tick=kill_the_leader_mid_mission)
    assert killed, "the mission ended before the leader could be killed"
    for k in (2, 3):
        took_over = [e for e in log_events(out / "logs" / f"agent-{k}.log") if e["event"] == "leader" and e["t"] > killed["t"]]
        assert took_over and took_over[0]["leader"] == 2, took_over
        assert took_over[0]["t"] - killed["t"] < 3.0, f"agent {k} followed 2 after {took_over[0]['t'] - killed['t']:.2f} s"
    survivors = {a["id"]: a for a in report["agents"] if a["id"] != 1}
    for k, agent in survivors.items():
        summary = json.loads((out / "agents" / f"agent-{k}.json").read_text())
        assert summary["exploration_done"], summary["exploration_done_reason"]
        assert agent["landed"] and agent["exit_code"] == 0, agent
    assert report["agents"][0]["exit_code"] == -signal.SIGKILL
    assert report["collisions"] == 0
    assert report["explored_fraction"] >= 0.9
    leaders_after = {entry["leader"] for entry in report["leaders"] if entry["t"] > 0 and 1 not in entry["members"]}
    assert 2 in leaders_after, report["leaders"]
    assert not processes_mentioning(str(out)), "swarm run left processes behind"


@pytest.mark.parametrize("strategy", ["uncoordinated", "frontier-only"])
def test_other_strategies_explore_the_box(tmp_path: Path, swarm_ports: SwarmPorts, strategy: str) -> None:
    out = tmp_path / "run"
    report = run_mission(_config(out, swarm_ports, **{
        "mission.drones": 2, "mission.max_time_s": 200.0, "explore.strategy": strategy,
    }), live=False)
    assert report["status"] == "complete", report["reason"]
    assert report["mission"]["strategy"] == strategy
    assert report["collisions"] == 0
    assert report["explored_fraction"] >= 0.9
    agents = report["agents"]
    if strategy == "uncoordinated":
        assert all(a["targets_self_selected"] > 0 and a["targets_assigned"] == 0 for a in agents), agents
        assert report["converged"] is True
    else:
        # frontiers and targets travel, patches do not: each drone holds only its own map
        assert agents[1]["targets_assigned"] > 0, agents
        assert all(a["patches_held"] == a["patches_sealed"] for a in agents), agents
        assert all(a["patches_received"] == {"push": 0, "pull": 0} for a in agents), agents
