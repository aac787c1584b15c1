"""An agent whose telemetry stops while airborne holds, then lands, and exits in phase failsafe (code 3).

The vehicle keeps obeying commands while its downlink is cut (the simulator's fault hook), as a real vehicle
with a one-way radio failure would; the test checks the vehicle really landed, from simulator truth.
"""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import pytest

from swarm.config import gcs_port
from swarm.sim.worlds import load_world
from tests.helpers import kill_all, swarm_cmd
from tests.sim.support import free_port_block, running_sim, sim_config, wait_until

pytestmark = pytest.mark.timeout(120)


def _events(log: Path) -> list[dict]:
    return [json.loads(line) for line in log.read_text().splitlines() if line.startswith("{")]


def test_telemetry_loss_holds_then_lands(tmp_path: Path) -> None:
    config = sim_config(free_port_block())
    world = load_world("box")
    log = tmp_path / "agent.log"
    with running_sim(config, world) as server:
        url = f"udpin://127.0.0.1:{gcs_port(config.sim, 1)}"
        agent = subprocess.Popen(
            swarm_cmd("agent", "--id", "1", "--autopilot", url, "--set", "agent.hover_s=60",
                      "--set", "explore.strategy=scripted"),
            stdout=log.open("w"), stderr=subprocess.STDOUT,
        )
        try:
            wait_until(lambda: any(e.get("phase") == "hovering" for e in _events(log)), 60, "hovering")
            assert server.status()["vehicles"][0]["position"][2] > 1.0  # airborne, by simulator truth
            cut_at = time.monotonic()
            server.set_telemetry_enabled(1, False)
            assert agent.wait(timeout=40) == 3
            failsafe = [e for e in _events(log) if e["event"] == "failsafe"]
            assert failsafe, log.read_text()
            wait_until(lambda: server.status()["vehicles"][0]["landed_state"] == "on_ground", 30, "vehicle landed")
            assert time.monotonic() - cut_at < 40
            commands = {e["command"]: e for e in _events(log) if e["event"] == "failsafe_command"}
            assert set(commands) == {"hold", "land"}
        finally:
            kill_all([agent])
