"""Bad input to `swarm run` is one clear line, a non-zero exit, and no process left behind."""

from __future__ import annotations

import socket
import subprocess
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import SwarmPorts, processes_mentioning, swarm_cmd

pytestmark = pytest.mark.sim


def run_bad(tmp_path: Path, ports: SwarmPorts, *args: str) -> tuple[int, str]:
    out = tmp_path / "run"
    result = subprocess.run(
        swarm_cmd("run", "--no-live", "--out", str(out), *ports.overrides(), *args),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert not processes_mentioning(str(out)), "processes left behind"
    assert "Traceback" not in result.stderr, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    return result.returncode, lines[0]


def test_unknown_world_name(tmp_path: Path, swarm_ports: SwarmPorts) -> None:
    code, line = run_bad(tmp_path, swarm_ports, "--world", "atlantis")
    assert code != 0
    assert "atlantis" in line and "office" in line  # names what exists


def test_unreadable_mesh(tmp_path: Path, swarm_ports: SwarmPorts) -> None:
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"\x00\x01not a mesh at all" * 10)
    code, line = run_bad(tmp_path, swarm_ports, "--world", str(garbage))
    assert code != 0 and "garbage.ply" in line


def test_empty_mesh(tmp_path: Path, swarm_ports: SwarmPorts) -> None:
    empty = tmp_path / "empty.ply"
    empty.write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 0\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
    )
    code, line = run_bad(tmp_path, swarm_ports, "--world", str(empty))
    assert code != 0 and "empty.ply" in line


def test_zero_drones(tmp_path: Path, swarm_ports: SwarmPorts) -> None:
    code, line = run_bad(tmp_path, swarm_ports, "--drones", "0")
    assert code == 2 and "--drones" in line


def test_start_inside_a_wall(tmp_path: Path, swarm_ports: SwarmPorts) -> None:
    from swarm.sim.worlds import load_world

    world = load_world("box")
    lo, hi = world.bounds
    xs = np.linspace(lo[0], hi[0], 400)
    probes = np.stack([xs, np.full_like(xs, (lo[1] + hi[1]) / 2), np.full_like(xs, 1.0)], axis=1)
    inside = probes[world.is_inside_solid(probes)]
    assert len(inside), "the box world should have walls"
    start = ",".join(f"{c:.3f}" for c in inside[len(inside) // 2])
    code, line = run_bad(tmp_path, swarm_ports, "--world", "box", "--start", start)
    assert code != 0 and "wall" in line


@pytest.mark.parametrize("which", ["gcs", "bus"])
def test_port_in_use(tmp_path: Path, swarm_ports: SwarmPorts, which: str) -> None:
    kind, port = (
        (socket.SOCK_DGRAM, swarm_ports.gcs_base + 1)
        if which == "gcs"
        else (socket.SOCK_STREAM, swarm_ports.bus_base + 2)
    )
    with socket.socket(socket.AF_INET, kind) as squatter:
        squatter.bind(("127.0.0.1", port))
        if kind == socket.SOCK_STREAM:
            squatter.listen()
        code, line = run_bad(tmp_path, swarm_ports, "--world", "box", "--drones", "2")
    assert code != 0
    assert str(port) in line and "in use" in line
