"""The simulator's status file and control file, through their models."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from swarm.files import FileFormatError, read_model, write_model
from swarm.sim.status import SimControl, SimStatus
from tests.file_models import sim_status, vehicle_status


def test_a_status_round_trips(tmp_path: Path) -> None:
    status = sim_status(
        vehicle_status(1, landed_state="in_air", armed=True),
        vehicle_status(2, closest_world_m=0.1, closest_world_at=[1.0, 2.0, 1.0]),
        collision_events=[{"t": 3.0, "kind": "drone", "vehicles": [1, 2], "position": [1.0, 1.0, 1.0]}],
        stalls=[{"t": 4.0, "s": 0.6}],
    )
    path = tmp_path / "sim.json"
    write_model(path, status, indent=None)
    back = read_model(path, SimStatus)
    assert back == status
    assert [v.landed_and_disarmed for v in back.vehicles] == [False, True]


def test_a_vehicle_without_its_landed_state_is_one_line(tmp_path: Path) -> None:
    data = sim_status().model_dump()
    del data["vehicles"][0]["landed_state"]
    path = tmp_path / "sim.json"
    path.write_text(json.dumps(data))
    with pytest.raises(FileFormatError, match=r"not a valid SimStatus: vehicles\[0\]\.landed_state: Field required"):
        read_model(path, SimStatus)


def test_the_control_file_round_trips(tmp_path: Path) -> None:
    path = tmp_path / "control.json"
    write_model(path, SimControl(telemetry_off=[2, 3]))
    assert read_model(path, SimControl).telemetry_off == [2, 3]
