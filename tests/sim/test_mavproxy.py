"""A ground station not written here flies the simulated PX4: MAVProxy (from PyPI) connects over UDP loopback as
it would to PX4 SITL, fetches the parameters, sets one, and the vehicle behaves by it (simulator truth):
COM_DISARM_PRFLT set to 2 s, then armed by MAVProxy's own command and left on the ground, it disarms itself after
2 s, not PX4's default 10 s."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from swarm.config import gcs_port
from swarm.sim.worlds import load_world
from tests.helpers import kill_all
from tests.sim.support import free_port_block, running_sim, sim_config, wait_until

pytestmark = [pytest.mark.timeout(90), pytest.mark.sim]

PREFLIGHT_DISARM_S = 2.0


def mavproxy() -> list[str]:
    found = shutil.which("mavproxy.py", path=str(Path(sys.executable).parent))
    assert found, "MAVProxy is a test dependency (pyproject.toml [test]): ./bootstrap.sh env installs it"
    return [sys.executable, found]


def test_mavproxy_sets_a_parameter_and_the_vehicle_flies_by_it(tmp_path: Path) -> None:
    config = sim_config(free_port_block())
    log = tmp_path / "mavproxy.out"
    with running_sim(config, load_world("box")) as server, log.open("w") as out:
        vehicle = server.vehicles[1]
        default = vehicle.params["COM_DISARM_PRFLT"]
        assert default == 10.0  # PX4's
        gcs = subprocess.Popen(
            [*mavproxy(), f"--master=udpin:127.0.0.1:{gcs_port(config.sim, 1)}"],
            stdin=subprocess.PIPE,
            stdout=out,
            stderr=subprocess.STDOUT,
            cwd=tmp_path,  # its telemetry log and parameter files land here
            env={**os.environ, "HOME": str(tmp_path)},  # no user's startup scripts
            text=True,
        )
        try:
            stdin = gcs.stdin
            assert stdin is not None

            def say(command: str) -> None:
                stdin.write(command + "\n")
                stdin.flush()

            # MAVProxy sets only parameters it has fetched (after trying MAVLink FTP, which the vehicle lacks)
            fetched = re.compile(r"Received (\d+) parameters")
            wait_until(lambda: fetched.search(log.read_text()) is not None, 45, "MAVProxy's parameter download")
            count = int(fetched.findall(log.read_text())[-1])
            assert count == len(vehicle.params), count
            say(f"param set COM_DISARM_PRFLT {PREFLIGHT_DISARM_S}")
            wait_until(lambda: vehicle.params["COM_DISARM_PRFLT"] == PREFLIGHT_DISARM_S, 15, "the parameter")
            say("arm throttle")
            wait_until(lambda: vehicle.autopilot.armed, 15, "armed by MAVProxy")
            armed_at = time.monotonic()
            wait_until(lambda: not vehicle.autopilot.armed, default, "the preflight disarm")
            held = time.monotonic() - armed_at
            wait_until(lambda: "DISARMED" in log.read_text(), 15, "MAVProxy to see the disarm")
        finally:
            kill_all([gcs])
    text = log.read_text()
    assert "ARMED" in text.replace("DISARMED", ""), text[-2000:]  # MAVProxy saw both
    assert PREFLIGHT_DISARM_S - 0.3 < held < default / 2, held
