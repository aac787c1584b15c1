"""The simulator's control file (`sim.control_path`): how `swarm run` silences a vehicle's downlink."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from swarm.config import load_config
from swarm.sim.server import SimServer
from swarm.sim.worlds import World


def _server(world: World, control: Path) -> SimServer:
    config = load_config(overrides={"mission.world": "box", "mission.drones": 3, "sim.control_path": str(control)})
    return SimServer(config, world)


def _write(path: Path, text: str, mtime_ns: int) -> None:
    path.write_text(text)
    os.utime(path, ns=(mtime_ns, mtime_ns))  # a new version, whatever the filesystem's timestamp granularity


def _sending(server: SimServer) -> dict[int, bool]:
    return {vid: v.telemetry_enabled for vid, v in server.vehicles.items()}


def test_control_file_silences_and_restores_vehicles(box_world: World, tmp_path: Path) -> None:
    control = tmp_path / "control.json"
    server = _server(box_world, control)
    server._read_control()  # no file: nothing changes
    assert _sending(server) == {1: True, 2: True, 3: True}
    _write(control, json.dumps({"telemetry_off": [2, 3]}), 1_000)
    server._read_control()
    assert _sending(server) == {1: True, 2: False, 3: False}
    _write(control, json.dumps({"telemetry_off": [3]}), 2_000)
    server._read_control()
    assert _sending(server) == {1: True, 2: True, 3: False}


@pytest.mark.parametrize("text", ["{", "[]", '{"telemetry_off": "all"}', '{"other": [1]}'])
def test_an_unreadable_control_file_is_reported_and_changes_nothing(
    box_world: World, tmp_path: Path, text: str, capsys: pytest.CaptureFixture[str]
) -> None:
    control = tmp_path / "control.json"
    server = _server(box_world, control)
    _write(control, json.dumps({"telemetry_off": [1]}), 1_000)
    server._read_control()
    _write(control, text, 2_000)
    server._read_control()
    assert _sending(server) == {1: False, 2: True, 3: True}
    assert "ignoring control file" in capsys.readouterr().err
