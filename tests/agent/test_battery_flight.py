"""An agent whose battery runs low goes home before PX4's battery failsafe would act: a real agent process, real
MAVSDK, the simulated vehicle (its battery, PX4's thresholds) over UDP loopback.

The battery starts at 28 % and hovers for 6 minutes when full (0.28 % a second): about 11 s after arming it is
below agent.battery_home_fraction (25 %), while the drone flies its route away from home; PX4's BAT_LOW_THR
(15 %) is another 36 s away, several times what the way back and the landing take.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from swarm.agent.summary import AgentSummary
from swarm.bus.phase import Phase
from swarm.files import read_model
from swarm.sim.worlds import load_world
from tests.agent.test_px4_params_flight import start_agent
from tests.helpers import kill_all, log_events
from tests.sim.support import free_port_block, running_sim, sim_config

pytestmark = [pytest.mark.timeout(150), pytest.mark.sim]

# out 4 m east of the take-off point (2, 3) in the box, then to and fro along x = 6 until the battery runs low
ROUTE = "agent.waypoints=[[6.0, 3.0, 1.5], [6.0, 1.5, 1.5], [6.0, 4.5, 1.5], [6.0, 1.5, 1.5], [6.0, 4.5, 1.5]]"


def test_a_low_battery_sends_the_agent_home_before_px4s_failsafe(tmp_path: Path) -> None:
    config = sim_config(free_port_block(), **{"sim.battery_start": 0.28, "sim.battery_minutes": 6.0})
    log, out = tmp_path / "agent.log", tmp_path / "out"
    with running_sim(config, load_world("box")) as server:
        agent = start_agent(config, log, "set", "--set", ROUTE, "--set", f"agent.out_dir={out}")
        try:
            assert agent.wait(timeout=120) == 0, log.read_text()[-3000:]
        finally:
            kill_all([agent])
        vehicle = server.status()["vehicles"][0]
        battery_left = server.vehicles[1].autopilot.battery.remaining
        bat_low_thr = server.vehicles[1].params["BAT_LOW_THR"]
    events = log_events(log)
    [low] = [e for e in events if e["event"] == "battery_low"]
    assert low["airborne"] and 0.2 < low["fraction"] < 0.25 and low["threshold"] == 0.25
    home = vehicle["home"]
    assert math.dist(low["position"][:2], home[:2]) > 2.0  # it was out on its route
    assert [e["phase"] for e in events if e["event"] == "flight_ended"] == [Phase.LANDED]
    # landed and disarmed above its take-off point (simulator truth)
    assert not vehicle["armed"] and vehicle["landed_state"] == "on_ground"
    assert math.dist(vehicle["position"][:2], home[:2]) < 0.4, vehicle
    # PX4's battery failsafe never had to act: no warning, no failsafe, the battery never reached BAT_LOW_THR
    texts = [e["text"] for e in events if e["event"] == "statustext"]
    assert not [t for t in texts if "battery" in t.lower() or t.startswith("Failsafe")], texts
    assert battery_left > bat_low_thr
    summary = read_model(out / "agent-1.json", AgentSummary)
    assert summary.landed and summary.battery_min_fraction is not None
    assert bat_low_thr < summary.battery_min_fraction < 0.25
    assert summary.battery_min_fraction == pytest.approx(battery_left, abs=0.011)  # percent steps, 0.5 Hz
