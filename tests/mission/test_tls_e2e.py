"""An authenticated swarm with a hostile member, end to end (issues 7 and 25): `swarm run` with mission.tls flies
the box world with every Zenoh session on mutual TLS and access control, and drone 3's agent is replaced by a
hostile one with drone 3's own certificate and signing key (tests/mission/hostile_agent.py): it flies, and from a
second session forges the others' patches, floods nested messages, sends an empty giant patch, lies as an
explorer and hammers the stores. The mission completes, the map converges, every survivor holds exactly the
patches sealed, byte for byte, and each attack is counted where it landed."""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from pathlib import Path

import pytest

from swarm.config import load_config
from swarm.mission import run as run_module
from swarm.mission.processes import swarm_command
from swarm.mission.report import read_summary
from swarm.mission.run import run_mission
from swarm.mission.soak import audit_patches
from tests.helpers import SwarmPorts

pytestmark = [pytest.mark.timeout(300), pytest.mark.mission]

ROOT = Path(__file__).resolve().parents[2]
HOSTILE = 3


def test_a_tls_mission_with_a_hostile_member_completes_with_every_map_intact(
    tmp_path: Path, swarm_ports: SwarmPorts, monkeypatch: pytest.MonkeyPatch
) -> None:
    def command(*args: str) -> list[str]:  # drone 3's agent is the hostile one; every other process is as ever
        if args[:1] == ("agent",) and args[-1].endswith(f"agent-{HOSTILE}.toml"):
            return [sys.executable, "-m", "tests.mission.hostile_agent", *args[1:]]
        return swarm_command(*args)

    monkeypatch.setattr(run_module, "swarm_command", command)
    monkeypatch.setenv("PYTHONPATH", str(ROOT))
    out = tmp_path / "run"
    config = load_config(
        overrides={
            "mission.world": "box",
            "mission.out": str(out),
            "mission.drones": 3,
            "mission.max_time_s": 150.0,
            "mission.tls": True,
            **swarm_ports.settings(),
        }
    )
    report = run_mission(config, live=False)

    hostile_log = (out / "logs" / f"agent-{HOSTILE}.log").read_text(errors="replace")
    sent = re.search(r"hostile member: sent (\{.*\})", hostile_log)
    assert sent is not None and "Traceback" not in hostile_log, hostile_log[-3000:]
    attacks = ast.literal_eval(sent.group(1))
    assert attacks["rounds"] >= 40 and attacks["forged_pushed"] > 0 and attacks["giant"] > 0, attacks
    assert report["status"] == "complete", report["reason"]
    assert report["explored_fraction"] >= 0.95
    assert report["converged"]
    audit = audit_patches(out, 3)
    assert audit.sealed > 0 and audit.lost == 0 and audit.unknown == 0, audit
    victims = {k: read_summary(out, k) for k in (1, 2)}
    forged = {k: s.sync.rejected.get("signer", 0) for k, s in victims.items() if s is not None}
    own = {k: s.traffic["patch_chunk"].dropped.get("own_id", 0) for k, s in victims.items() if s is not None}
    assert sum(forged.values()) > 0, forged  # forgeries in the other's name, pulled from the liar's store
    assert sum(own.values()) > 0, own  # forgeries of its own next ids, served by the liar
    for summary in victims.values():
        assert summary is not None
        rejected = summary.sync.rejected
        assert rejected.get("empty", 0) > 0, rejected  # the giant patch with no observed voxel
        dropped = summary.traffic["patch_chunk"].dropped
        assert dropped.get("pushed_relay", 0) > 0, dropped
        assert sum(summary.traffic["state"].dropped.values()) > 0  # nested arrays
        assert any(int(asker) > 3 for asker in summary.sync.served_to), summary.sync.served_to  # spoofed names
    leader = read_summary(out, 1)
    assert leader is not None
    lies = leader.exploration_rejected
    assert lies.get("visited_off_track", 0) + lies.get("visited_outside_volume", 0) > 0, lies
    for name in ("observer", "agent-1", "agent-2"):
        bus = tomllib.loads((out / "config" / f"{name}.toml").read_text())["bus"]
        assert bus["tls_dir"] == str(out / "certs")
        assert bus["tls_name"] == ("observer" if name == "observer" else f"drone-{name[-1]}")
        assert all(e.startswith("tls/") for e in bus["listen"] + bus["connect"]), bus
    tls = {"ca.pem", "observer.pem"} | {f"drone-{k}.pem" for k in (1, 2, 3)}
    assert {p.name for p in (out / "certs").glob("*.pem")} == tls | {f"drone-{k}.sign.pem" for k in (1, 2, 3)}
    for k in (1, 2):
        log = (out / "logs" / f"agent-{k}.log").read_text(errors="replace")
        assert not re.search(r"\bERROR\b", re.sub(r"\x1b\[[0-9;]*m", "", log)), f"Zenoh errors in agent {k}'s log"
