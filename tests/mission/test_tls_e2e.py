"""An authenticated swarm end to end (issue 7): `swarm run` with mission.tls flies the box world with every
Zenoh session on mutual TLS and access control, and the map still converges."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

from swarm.config import load_config
from swarm.mission.report import held_patch_ids, read_summary, sealed_patch_ids
from swarm.mission.run import run_mission
from tests.helpers import SwarmPorts

pytestmark = [pytest.mark.timeout(300), pytest.mark.mission]


def test_a_mission_over_mutual_tls_completes_and_converges(tmp_path: Path, swarm_ports: SwarmPorts) -> None:
    out = tmp_path / "run"
    config = load_config(
        overrides={
            "mission.world": "box",
            "mission.out": str(out),
            "mission.drones": 2,
            "mission.max_time_s": 150.0,
            "mission.tls": True,
            **swarm_ports.settings(),
        }
    )
    report = run_mission(config, live=False)

    assert report["status"] == "complete", report["reason"]
    assert report["explored_fraction"] >= 0.95
    assert report["converged"]
    sealed = sealed_patch_ids(out / "agents" / "patches")
    for k in (1, 2):
        summary = read_summary(out, k)
        assert summary is not None and held_patch_ids(summary) == sealed
    for name in ("observer", "agent-1", "agent-2"):
        bus = tomllib.loads((out / "config" / f"{name}.toml").read_text())["bus"]
        assert bus["tls_dir"] == str(out / "certs")
        assert bus["tls_name"] == ("observer" if name == "observer" else f"drone-{name[-1]}")
        assert all(e.startswith("tls/") for e in bus["listen"] + bus["connect"]), bus
    assert {p.name for p in (out / "certs").glob("*.pem")} == {"ca.pem", "drone-1.pem", "drone-2.pem", "observer.pem"}
    for k in (1, 2):
        log = (out / "logs" / f"agent-{k}.log").read_text(errors="replace")
        assert not re.search(r"\bERROR\b", re.sub(r"\x1b\[[0-9;]*m", "", log)), f"Zenoh errors in agent {k}'s log"
