"""A vehicle taken out of offboard by someone else is not fought for: a real agent process flies a scripted route
against the simulated vehicle (real MAVSDK, UDP loopback); mid-route the vehicle is switched to Land, as a pilot's
mode switch or PX4's own failsafe would. The agent must not enter offboard again: it logs taken_over, commands
nothing more, watches the vehicle land where it was, and ends in phase failsafe."""

from __future__ import annotations

import math

import pytest

from swarm.bus.phase import Phase
from swarm.sim.px4 import FlightMode
from swarm.sim.worlds import load_world
from tests.agent.test_px4_params_flight import start_agent
from tests.helpers import kill_all, log_events
from tests.sim.support import free_port_block, running_sim, sim_config, wait_until

pytestmark = [pytest.mark.timeout(150), pytest.mark.sim]

ROUTE = "agent.waypoints=[[8.0, 3.0, 1.5], [8.0, 6.0, 1.5], [2.0, 6.0, 1.5]]"
EXIT_FAILSAFE = 3


def test_an_agent_does_not_fight_a_mode_switch_it_did_not_ask_for(tmp_path) -> None:
    config = sim_config(free_port_block())
    log = tmp_path / "agent.log"
    with running_sim(config, load_world("box")) as server:
        vehicle = server.vehicles[1].autopilot
        agent = start_agent(config, log, "set", "--set", ROUTE)
        try:
            wait_until(lambda: vehicle.mode == FlightMode.OFFBOARD and vehicle.position[0] > 4.0, 60, "on its route")
            with server._lock:  # as a pilot's switch: the simulator's own thread runs the vehicle
                vehicle.land()
            switched_at = vehicle.position.copy()
            assert agent.wait(timeout=60) == EXIT_FAILSAFE, log.read_text()[-3000:]
        finally:
            kill_all([agent])
        status = server.status()["vehicles"][0]
    events = log_events(log)
    [taken] = [e for e in events if e["event"] == "taken_over"]
    assert taken["mode"] == "LAND", taken
    assert [e for e in events if e["event"] == "taken_over_landed"]
    assert [e["phase"] for e in events if e["event"] == "flight_ended"] == [Phase.FAILSAFE]
    # it landed under the switch, not back at the route or at home: the agent did not take the vehicle back
    assert not status["armed"] and status["landed_state"] == "on_ground"
    assert math.dist(status["position"][:2], switched_at[:2]) < 1.0, (status["position"], switched_at)
