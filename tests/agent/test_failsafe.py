"""An agent whose telemetry stops while airborne holds, then lands, sees the landing through once telemetry is
back, and exits in phase failsafe (code 3).

The vehicle keeps obeying commands while its downlink is cut (the simulator's fault hook), as a real vehicle
with a one-way radio failure would. While it descends, the simulator switches it to HOLD, as MAVSDK's retry of
the unanswered hold command arriving after LAND did in a soak; the agent must notice and land it again. The
test checks the vehicle really landed, from simulator truth.
"""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import pytest

from swarm.bus.phase import Phase
from swarm.config import gcs_port
from swarm.sim.worlds import load_world
from tests.helpers import kill_all, swarm_cmd
from tests.sim.support import free_port_block, running_sim, sim_config, wait_until

pytestmark = [pytest.mark.timeout(120), pytest.mark.sim]


def _events(log: Path) -> list[dict]:
    return [json.loads(line) for line in log.read_text().splitlines() if line.startswith("{")]


def _height(server) -> float:
    vehicle = server.status()["vehicles"][0]
    return vehicle["position"][2] - vehicle["home"][2]


def test_telemetry_loss_holds_then_lands_and_a_late_hold_is_landed_again(tmp_path: Path) -> None:
    config = sim_config(free_port_block())
    world = load_world("box")
    log = tmp_path / "agent.log"
    with running_sim(config, world) as server:
        url = f"udpin://127.0.0.1:{gcs_port(config.sim, 1)}"
        agent = subprocess.Popen(
            swarm_cmd(
                "agent",
                "--id",
                "1",
                "--autopilot",
                url,
                "--set",
                "agent.hover_s=60",
                "--set",
                "agent.px4_params=set",  # the simulator has PX4's defaults: the agent makes offboard loss a Hold
                "--set",
                "agent.altitude_m=2.5",
                "--set",
                "explore.strategy=scripted",
                "--set",
                "camera.source=none",
            ),  # flight only: no camera driver runs
            stdout=log.open("w"),
            stderr=subprocess.STDOUT,
        )
        try:
            wait_until(lambda: any(e.get("phase") == Phase.HOVERING for e in _events(log)), 60, "hovering")
            assert server.status()["vehicles"][0]["position"][2] > 2.0  # airborne, by simulator truth
            cut_at = time.monotonic()
            server.set_telemetry_enabled(1, False)
            wait_until(
                lambda: any(e["event"] == "failsafe_command" and e["command"] == "land" for e in _events(log)),
                15,
                "the failsafe land command",
            )
            server.set_telemetry_enabled(1, True)
            # MAVSDK retries an unacknowledged command for about 1.5 s; HOLD once the vehicle has been descending
            # for longer, or a retried LAND would undo it (when that happens this test fails, it cannot pass)
            wait_until(lambda: _height(server) < 1.2, 15, "the failsafe descent")
            server.hold(1)
            vehicle = server.status()["vehicles"][0]
            assert vehicle["mode"] == "HOLD" and vehicle["landed_state"] != "on_ground", vehicle
            assert agent.wait(timeout=40) == 3
            events = _events(log)
            assert any(e["event"] == "failsafe" for e in events), log.read_text()
            commands = {e["command"]: e for e in events if e["event"] == "failsafe_command"}
            assert set(commands) == {"hold", "land"}
            relands = [e for e in events if e["event"] == "reland"]
            assert relands and relands[0]["mode"] == "HOLD", log.read_text()
            assert any(e["event"] == "failsafe_landed" for e in events), log.read_text()
            vehicle = server.status()["vehicles"][0]
            assert vehicle["landed_state"] == "on_ground" and not vehicle["armed"], vehicle
            assert time.monotonic() - cut_at < 40
        finally:
            kill_all([agent])
