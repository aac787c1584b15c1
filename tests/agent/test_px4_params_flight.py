"""agent.px4_params against the simulated vehicle, which starts with PX4's defaults (an agent death is a Return
that climbs to 60 m): a real agent process, real MAVSDK, the simulator over UDP loopback.

- check: the agent refuses to take off, names each blocking parameter, exits 1; the drone never arms;
- set: the agent writes the Hold values and reads them back; frozen, its drone holds and the agent logs the
  vehicle's STATUSTEXT when it wakes; killed while hovering, its drone holds;
- off: the agent touches nothing and flies.
"""

from __future__ import annotations

import signal
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from swarm.bus.phase import Phase
from swarm.config import SwarmConfig, gcs_port
from swarm.sim.server import SimServer
from swarm.sim.worlds import load_world
from tests.helpers import kill_all, log_events, swarm_cmd
from tests.sim.support import free_port_block, running_sim, sim_config, wait_until

pytestmark = [pytest.mark.timeout(120), pytest.mark.sim]

PX4_DEFAULTS = {"COM_OBL_RC_ACT": 0, "NAV_RCL_ACT": 2, "NAV_DLL_ACT": 0, "COM_RCL_EXCEPT": 0, "COM_LOW_BAT_ACT": 0}


def start_agent(config: SwarmConfig, log: Path, mode: str, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        swarm_cmd(
            "agent",
            "--id",
            "1",
            "--autopilot",
            f"udpin://127.0.0.1:{gcs_port(config.sim, 1)}",
            "--set",
            f"agent.px4_params={mode}",
            "--set",
            "agent.hover_s=60",
            "--set",
            "agent.altitude_m=1.5",
            "--set",
            "explore.strategy=scripted",
            "--set",
            "camera.source=none",
            *extra,
        ),
        stdout=log.open("w"),
        stderr=subprocess.STDOUT,
    )


@contextmanager
def agent_on_sim(tmp_path: Path, mode: str, *extra: str) -> Iterator[tuple[SimServer, subprocess.Popen, Path]]:
    """A simulated vehicle with PX4's defaults and one agent process (agent.px4_params = `mode`) flying it:
    (simulator, agent, agent log). The agent is killed afterwards, also when the test fails."""
    config = sim_config(free_port_block())
    log = tmp_path / "agent.log"
    with running_sim(config, load_world("box")) as server:
        agent = start_agent(config, log, mode, *extra)
        try:
            yield server, agent, log
        finally:
            kill_all([agent])


def params(server: SimServer) -> dict[str, float]:
    p = server.vehicles[1].params
    return {name: p[name] for name in PX4_DEFAULTS}


def height(server: SimServer) -> float:
    v = server.status()["vehicles"][0]
    return float(v["position"][2] - v["home"][2])


def test_check_with_px4_defaults_refuses_to_take_off_and_names_the_parameter(tmp_path: Path) -> None:
    with agent_on_sim(tmp_path, "check") as (server, agent, log):
        assert agent.wait(timeout=60) == 1
        events = log_events(log)
        unsafe = [e for e in events if e["event"] == "px4_param_unsafe"]
        assert [(e["param"], e["value"]) for e in unsafe] == [("NAV_RCL_ACT", 2)], log.read_text()
        assert "RTL_RETURN_ALT=60 m" in unsafe[0]["reason"]
        [error] = [e["reason"] for e in events if e["event"] == "flight_error"]
        assert "refusing to take off" in error and "NAV_RCL_ACT=2" in error
        assert not any(e.get("phase") == Phase.TAKEOFF for e in events)
        vehicle = server.status()["vehicles"][0]
        assert not vehicle["armed"] and vehicle["distance_m"] == 0.0  # never left the ground
        assert params(server) == PX4_DEFAULTS  # check writes nothing


def test_set_writes_hold_values_a_frozen_or_killed_agents_drone_holds(tmp_path: Path) -> None:
    route = "agent.waypoints=[[5.5, 3.0, 1.5], [2.5, 3.0, 1.5]]"  # flown in offboard
    with agent_on_sim(tmp_path, "set", "--set", route) as (server, agent, log):
        wait_until(lambda: any(e.get("phase") == Phase.FLYING for e in log_events(log)), 60, "flying")
        assert params(server) == {**PX4_DEFAULTS, "COM_OBL_RC_ACT": 5, "NAV_RCL_ACT": 1}  # simulator truth
        [written] = [e for e in log_events(log) if e["event"] == "px4_params_set"]
        assert written["read_back"] == written["written"] == {"COM_OBL_RC_ACT": 5, "NAV_RCL_ACT": 1}
        # frozen, the agent sends no setpoints: the vehicle holds and says so; woken, the agent logs it. The agent
        # logs FLYING before its first setpoint, while the vehicle still holds after the take-off: freezing it then
        # would find HOLD at once, with no offboard to lose
        wait_until(lambda: server.status()["vehicles"][0]["mode"] == "OFFBOARD", 10, "offboard")
        agent.send_signal(signal.SIGSTOP)
        try:
            wait_until(lambda: server.status()["vehicles"][0]["mode"] == "HOLD", 5, "offboard loss while frozen")
        finally:
            agent.send_signal(signal.SIGCONT)
        wait_until(
            lambda: any(
                e["event"] == "statustext" and e["text"].startswith("Failsafe: no offboard signal, Hold")
                for e in log_events(log)
            ),
            10,
            "the failsafe STATUSTEXT in the agent's log",
        )
        wait_until(lambda: any(e.get("phase") == Phase.HOVERING for e in log_events(log)), 60, "hovering")
        assert server.status()["vehicles"][0]["mode"] == "OFFBOARD"  # it flew on after waking
        agent.kill()
        agent.wait(timeout=10)
        wait_until(lambda: server.status()["vehicles"][0]["mode"] != "OFFBOARD", 5, "offboard loss")
        assert server.status()["vehicles"][0]["mode"] == "HOLD"
        held_at = height(server)
        time.sleep(2.0)  # an observation window: the drone must still hover there, not climb
        assert abs(height(server) - held_at) < 0.15 and held_at < 1.8
        assert server.status()["vehicles"][0]["mode"] == "HOLD"


def test_off_leaves_the_parameters_and_flies(tmp_path: Path) -> None:
    with agent_on_sim(tmp_path, "off") as (server, agent, log):
        wait_until(lambda: any(e.get("phase") == Phase.HOVERING for e in log_events(log)), 60, "hovering")
        events = log_events(log)
        assert not any(e["event"].startswith("px4_param") for e in events), log.read_text()
        assert params(server) == PX4_DEFAULTS
        assert height(server) > 1.2
        agent.terminate()  # SIGTERM: the agent lands the drone before it exits
        assert agent.wait(timeout=40) == 0
        assert not server.status()["vehicles"][0]["armed"]
