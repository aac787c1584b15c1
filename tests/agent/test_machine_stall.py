"""A stall of the whole machine is not a lost link: the simulator and an airborne agent, both real processes, are
stopped for 1.8 s (as when the machine does not run them; the agent 0.2 s after the simulator) and continued;
the agent, which did not run either, does not count that silence and flies on. The other half of the rule, a
link that stops while the agent listens, is `test_failsafe.py`."""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path

import pytest

from swarm.bus.phase import Phase
from tests.helpers import kill_all, log_events, swarm_cmd
from tests.sim.support import free_port_block, wait_until

pytestmark = [pytest.mark.timeout(120), pytest.mark.sim, pytest.mark.alone]  # stalls are timed

FREEZE_S = 1.8  # longer than the 1.5 s telemetry timeout, shorter than the 2 s that counted as a stall before
DRAIN_S = 0.2  # loopback delivers in milliseconds; the agent then listens this long, well under the 0.5 s asserted


def test_a_stall_of_simulator_and_agent_together_is_not_taken_for_a_lost_link(tmp_path: Path) -> None:
    base = free_port_block()
    ports = [
        "--set",
        f"sim.vehicle_base_port={base}",
        "--set",
        f"sim.gcs_base_port={base + 20}",
        "--set",
        "camera.source=none",
        "--set",
        "explore.strategy=scripted",
    ]  # flight only: no sensor router
    sim_log, log = tmp_path / "sim.log", tmp_path / "agent.log"
    sim = subprocess.Popen(
        swarm_cmd("sim", "--world", "box", "--vehicles", "1", *ports),
        stdout=sim_log.open("w"),
        stderr=subprocess.STDOUT,
    )
    agent = subprocess.Popen(
        swarm_cmd(
            "agent",
            "--id",
            "1",
            "--autopilot",
            f"udpin://127.0.0.1:{base + 20}",
            *ports,
            "--set",
            "agent.hover_s=12",
            "--set",
            "agent.px4_params=set",  # the simulator has PX4's defaults: the agent makes offboard loss a Hold
            "--set",
            "agent.altitude_m=2.0",
            "--set",
            "explore.strategy=scripted",
        ),
        stdout=log.open("w"),
        stderr=subprocess.STDOUT,
    )
    try:
        wait_until(lambda: any(e.get("phase") == Phase.HOVERING for e in log_events(log)), 60, "hovering")
        # The vehicle first, and the agent once the vehicle's last samples, still on their way through
        # mavsdk_server, have reached it: stopped with them unread, it would read them on waking as fresh (a
        # sample is dated when the agent reads it), then hear the still stopped vehicle's silence and fail safe.
        sim.send_signal(signal.SIGSTOP)
        time.sleep(DRAIN_S)
        agent.send_signal(signal.SIGSTOP)
        time.sleep(FREEZE_S)
        # The agent first, and the vehicle only once the agent has looked at its telemetry: on a loaded machine
        # the vehicle's next samples could otherwise reach the agent before it ran, and it would see no gap at all.
        agent.send_signal(signal.SIGCONT)
        wait_until(lambda: any(e["event"] == "telemetry_gap_unheard" for e in log_events(log)), 10, "the gap seen")
        sim.send_signal(signal.SIGCONT)
        assert agent.wait(timeout=60) == 0, log.read_text()
        events = log_events(log)
        assert not [e for e in events if e["event"].startswith("failsafe")], log.read_text()
        [gap] = [e for e in events if e["event"] == "telemetry_gap_unheard"]
        assert gap["age"] > 1.5 and gap["heard"] < 0.5, gap
        assert [e["phase"] for e in events if e["event"] == "phase"][-2:] == [Phase.LANDING, Phase.LANDED]
    finally:
        kill_all([agent])
        sim.send_signal(signal.SIGCONT)
        sim.send_signal(signal.SIGINT)
        kill_all([sim])
