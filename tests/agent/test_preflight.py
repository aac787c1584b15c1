"""`swarm agent --check` against the simulated vehicle with PX4's defaults: a real CLI process, real MAVSDK,
the simulator over UDP loopback. It reports health and the failsafe parameters, says whether the agent would
fly, and never arms or writes."""

from __future__ import annotations

import subprocess

import pytest

from swarm.config import gcs_port
from swarm.sim.worlds import load_world
from tests.agent.test_px4_params_flight import PX4_DEFAULTS, params
from tests.helpers import swarm_cmd
from tests.sim.support import free_port_block, running_sim, sim_config

pytestmark = [pytest.mark.timeout(120), pytest.mark.sim]


def check(port: int, *settings: str, timeout_s: float = 60) -> subprocess.CompletedProcess[str]:
    overrides = [arg for s in settings for arg in ("--set", s)]
    command = swarm_cmd("agent", "--id", "1", "--autopilot", f"udpin://127.0.0.1:{port}", "--check", *overrides)
    return subprocess.run(command, capture_output=True, text=True, timeout=timeout_s)


@pytest.mark.parametrize(
    ("mode", "code", "says"),
    [
        ("check", 1, "problem: NAV_RCL_ACT=2: "),
        ("set", 0, "the agent would write COM_OBL_RC_ACT=5, NAV_RCL_ACT=1 before arming"),
        ("off", 0, "reads and writes no parameter"),
    ],
)
def test_check_reports_what_the_agent_would_do_and_changes_nothing(mode: str, code: int, says: str) -> None:
    config = sim_config(free_port_block())
    with running_sim(config, load_world("box")) as server:
        result = check(gcs_port(config.sim, 1), f"agent.px4_params={mode}")
        vehicle = server.status()["vehicles"][0]
        assert not vehicle["armed"] and vehicle["distance_m"] == 0.0
        assert params(server) == PX4_DEFAULTS
    assert result.returncode == code, result.stdout + result.stderr
    out = result.stdout
    assert "health armable: ok" in out and "health home position: ok" in out
    assert says in out
    assert ("param COM_OBL_RC_ACT = 0" in out) == (mode != "off")
    assert out.strip().endswith("would take off" if code == 0 else "would refuse to fly")


def test_check_with_no_autopilot_says_so_and_exits_1() -> None:
    port = free_port_block()
    result = check(port, "agent.connect_timeout_s=2", timeout_s=30)
    assert result.returncode == 1
    assert f"problem: no autopilot heartbeat on udpin://127.0.0.1:{port} within 2 s" in result.stdout
