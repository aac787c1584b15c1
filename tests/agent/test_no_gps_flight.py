"""An agent flies a vehicle without GPS in its local frame: a real agent process, real MAVSDK, the simulated
vehicle booted with GPS off (no global position, no home position, no Hold) over UDP loopback, its local origin
1.5 m away from its take-off point. The agent is told where that origin is (agent.frame = "local"), takes off and
holds in offboard, and must pass over each world waypoint of its route (simulator truth) and land at its end."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest

from swarm.bus.phase import Phase
from swarm.sim.worlds import load_world
from tests.agent.test_px4_params_flight import start_agent
from tests.helpers import kill_all, log_events
from tests.sim.support import free_port_block, running_sim, sim_config

pytestmark = [pytest.mark.timeout(150), pytest.mark.sim]

OFFSET = (1.2, -0.9, 0.0)  # the vehicle's local origin from its take-off point
WAYPOINTS = [(5.0, 3.0, 1.5), (5.0, 5.0, 1.5), (3.0, 5.0, 1.5)]


def test_an_agent_flies_without_gps_in_the_local_frame(tmp_path: Path) -> None:
    config = sim_config(free_port_block(), **{"sim.gps": False, "sim.local_origin_offset": list(OFFSET)})
    log = tmp_path / "agent.log"
    with running_sim(config, load_world("box")) as server:
        vehicle = server.vehicles[1].autopilot
        spawn = vehicle.home.copy()
        origin = [float(v) for v in spawn + OFFSET]  # what the operator measured and configured
        agent = start_agent(
            config,
            log,
            "set",
            "--set",
            "agent.frame=local",
            "--set",
            f"agent.local_origin={origin}",
            "--set",
            f"agent.waypoints={[list(w) for w in WAYPOINTS]}",
            "--set",
            "agent.hover_s=1",
        )
        track: list[np.ndarray] = []
        try:
            deadline = time.monotonic() + 120
            while agent.poll() is None and time.monotonic() < deadline:
                track.append(vehicle.position.copy())
                time.sleep(0.05)
            assert agent.wait(timeout=5) == 0, log.read_text()[-3000:]
        finally:
            kill_all([agent])
        status = server.status()["vehicles"][0]
    assert not status["global_position"]  # it never had one
    path = np.array(track)
    for w in WAYPOINTS:
        assert np.min(np.linalg.norm(path - w, axis=1)) < 0.35, (w, path[-1])
    assert not status["armed"] and status["landed_state"] == "on_ground"
    assert math.dist(status["position"][:2], WAYPOINTS[-1][:2]) < 0.3, status  # a route lands where it ends
    events = log_events(log)
    assert [e["phase"] for e in events if e["event"] == "flight_ended"] == [Phase.LANDED]
    texts = [e["text"] for e in events if e["event"] == "statustext"]
    assert not [t for t in texts if "not possible" in t or t.startswith("Failsafe")], texts
    assert not [e for e in events if e["event"] == "flight_error"], [e for e in events if e["event"] == "flight_error"]
