"""`sim_command` (the body of `swarm sim`) in its own process: endpoints printed, runs until SIGINT, summary."""

import queue
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest

from swarm.config import load_config
from swarm.errors import WorldError
from swarm.sim.server import sim_command

SCRIPT = """
import sys
from swarm.config import load_config
from swarm.sim.server import sim_command
sys.exit(sim_command(load_config(overrides={{
    "mission.world": "box", "mission.drones": 2,
    "sim.vehicle_base_port": {vbase}, "sim.gcs_base_port": {gbase}, "camera.stream.connect": ["tcp/127.0.0.1:{sbase}"],
}})))
"""


class LineReader:
    """Reads a process's stdout in a helper thread, so that a silent process cannot hang the test."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self._lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=lambda: [self._lines.put(line) for line in proc.stdout], daemon=True).start()

    def take(self, count: int, timeout: float) -> list[str]:
        got: list[str] = []
        deadline = time.monotonic() + timeout
        while len(got) < count:
            try:
                got.append(self._lines.get(timeout=max(0.0, deadline - time.monotonic())).rstrip("\n"))
            except queue.Empty:
                raise AssertionError(f"only got {got}") from None
        return got


@pytest.mark.sim
def test_sim_command_prints_endpoints_and_stops_on_sigint(port_base: int) -> None:
    gbase = port_base + 20
    script = SCRIPT.format(vbase=port_base, gbase=gbase, sbase=port_base + 40)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    reader = LineReader(proc)
    try:
        lines = reader.take(3, timeout=30)
        # the agent's command line carries the mission volume: an agent loads no world
        assert lines[0] == (
            f"vehicle 1: MAVLink udp 127.0.0.1:{port_base} -> 127.0.0.1:{gbase}"
            f"  (agent: swarm agent --id 1 --autopilot udpin://0.0.0.0:{gbase} --set agent.px4_params=set "
            "--set 'mission.volume={min=[0, 0, -0.2],max=[8, 6, 3.1995]}')"
        )
        assert lines[1].startswith(f"vehicle 2: MAVLink udp 127.0.0.1:{port_base + 1} -> 127.0.0.1:{gbase + 1}")
        # alone, the simulator is the sensor router where the cameras and the agents dial (camera.stream.connect)
        assert lines[2] == (
            f"sensor streams: odometry on tcp/127.0.0.1:{port_base + 40} (the depth cameras: "
            "swarm cameras --world box --vehicles 2)"
        )
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10)
        err = proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    summary = reader.take(1, timeout=5)
    assert summary[0].startswith("sim stopped after ")
    assert "0 collisions" in summary[0] and "1: 0.0 m" in summary[0]


@pytest.mark.sim
def test_an_agent_listening_before_the_sim_starts_gets_a_warning_not_an_error(port_base: int) -> None:
    gbase = port_base + 20
    agent = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    agent.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as MAVSDK's udpin binds
    agent.bind(("0.0.0.0", gbase))
    agent.settimeout(10)
    script = SCRIPT.format(vbase=port_base, gbase=gbase, sbase=port_base + 40)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        data, addr = agent.recvfrom(2048)  # the vehicle's telemetry reaches the early listener
        assert addr[1] == port_base and data[0] == 0xFD  # MAVLink 2 from vehicle 1's port
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10)
    finally:
        agent.close()
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    err = proc.stderr.read()
    assert proc.returncode == 0, err
    assert f"warning: UDP port {gbase} (GCS of vehicle 1) is already bound" in err
    assert str(gbase + 1) not in err


def test_sim_command_unknown_world_is_a_world_error() -> None:
    with pytest.raises(WorldError, match="atlantis"):
        sim_command(load_config(overrides={"mission.world": "atlantis"}))
