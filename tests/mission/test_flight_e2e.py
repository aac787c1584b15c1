"""End to end: real `swarm sim`, `swarm agent` and `swarm observe` processes, real Zenoh on loopback, real MAVSDK
talking MAVLink over UDP to the simulated vehicles. Small world, short flights."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from swarm.bus.phase import Phase
from tests.helpers import SwarmPorts, kill_all, log_events, processes_mentioning, swarm_cmd

pytestmark = [pytest.mark.timeout(240), pytest.mark.mission]


def run_swarm(out: Path, ports: SwarmPorts, *args: str, timeout: float = 200) -> subprocess.CompletedProcess[str]:
    cmd = swarm_cmd("run", "--no-live", "--out", str(out), *ports.overrides(), *args)
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


def _mavsdk_temp_dirs() -> set[Path]:
    """The directories MAVSDK leaves behind, in /tmp and in this session's TMPDIR (tests/conftest.py)."""
    places = {Path("/tmp"), Path(os.environ.get("TMPDIR", "/tmp"))}
    return {p for place in places for p in place.glob("mavsdk-component-metadata-*")}


def test_two_agents_fly_see_each_other_and_land(tmp_path: Path, swarm_ports: SwarmPorts) -> None:
    out = tmp_path / "run"
    left_before = _mavsdk_temp_dirs()
    result = run_swarm(out, swarm_ports, "--drones", "2", "--world", "box", "--max-time", "150")
    assert result.returncode == 0, result.stdout + result.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["status"] == "complete"
    assert report["collisions"] == 0, report["collision_events"]
    assert report["drones"] == 2 and report["world"] == "box"
    assert [a["id"] for a in report["agents"]] == [1, 2]
    for agent in report["agents"]:
        other = 3 - agent["id"]
        assert agent["landed"], agent
        assert agent["peers_seen"] == [other], agent
        assert agent["distance_m"] > 2.0, agent  # truth from the simulator: the drone really flew
        assert agent["bytes_sent"] > 0 and agent["bytes_received"] > 0
        assert agent["patches_sealed"] > 0 and agent["frames"] > 0
        assert (out / "agents" / f"agent-{agent['id']}.ply").stat().st_size > 0
    # the swarm's map: every sealed patch fused by the observer, checked against the world mesh
    assert report["map"] == "map.ply" and (out / "map.ply").stat().st_size > 0
    # autonomous exploration (coordinated, the default): drone 1 leads, drone 2 flies the targets it is given,
    # and the leader ends the mission when no frontier is left
    assert report["mission"]["strategy"] == "coordinated"
    assert report["explored_fraction"] >= 0.95
    assert report["time_to"]["0.5"] is not None and report["time_to"]["0.5"] <= report["time_to"]["0.95"]
    assert report["agents"][1]["targets_assigned"] > 0 and report["agents"][1]["targets_self_selected"] == 0
    # drone 1 leads whenever both are in one cluster (before they hear each other, each leads itself)
    together = [e for e in report["leaders"] if sorted(e["members"]) == [1, 2]]
    assert together and all(e["leader"] == 1 for e in together), report["leaders"]
    summaries = {k: json.loads((out / "agents" / f"agent-{k}.json").read_text()) for k in (1, 2)}
    assert summaries[1]["exploration_done"] and "no reachable frontier left" in summaries[1]["exploration_done_reason"]
    assert summaries[2]["exploration_done"] and "leader 1 declared" in summaries[2]["exploration_done_reason"]
    assert set(report["plots"]) == {"explored.png", "trajectories.png", "leaders.png", "bytes.png"}
    assert all((out / name).stat().st_size > 0 for name in report["plots"])
    assert "explored" in (out / "report.md").read_text()
    sealed = sum(a["patches_sealed"] for a in report["agents"])
    assert len(list((out / "agents" / "patches").glob("*.patch"))) == sealed
    observer = json.loads((out / "observer.json").read_text())
    assert observer["patches_fused"] == sealed and observer["patches_rejected"] == {}
    # map sharing: each drone ended holding every patch, its own and the other's (pushed, or pulled if lost)
    assert report["converged"] is True
    for agent in report["agents"]:
        assert agent["patches_held"] == sealed, agent
        other_sealed = sealed - agent["patches_sealed"]
        assert agent["patches_received"]["push"] + agent["patches_received"]["pull"] == other_sealed, agent
        assert agent["patches_rejected"] == {}
    digests = {json.loads((out / "agents" / f"agent-{k}.json").read_text())["fused_digest"] for k in (1, 2)}
    assert len(digests) == 1, "the two drones' fused maps differ"
    bandwidth = report["bandwidth"]
    assert 0 < bandwidth["bytes_per_agent_s"] < bandwidth["whole_map_baseline_bytes_per_agent_s"]
    assert not processes_mentioning(str(out)), "swarm run left processes behind"
    assert _mavsdk_temp_dirs() == left_before and not (out / "agents" / "tmp").exists()  # nor temporary dirs


def test_mesh_file_world_with_start(tmp_path: Path, swarm_ports: SwarmPorts) -> None:
    from swarm.sim.worlds import load_world

    mesh = tmp_path / "room.ply"
    world = load_world("box")
    world.save(mesh)
    start = ",".join(f"{c:.2f}" for c in world.default_start)
    out = tmp_path / "run"
    result = run_swarm(out, swarm_ports, "--drones", "1", "--world", str(mesh), "--start", start, "--max-time", "120")
    assert result.returncode == 0, result.stdout + result.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["status"] == "complete", report["reason"]
    assert report["collisions"] == 0, report["collision_events"]
    assert report["agents"][0]["landed"]
    assert report["explored_fraction"] >= 0.95  # one drone explores a mesh world alone


def _wait_for(log: Path, predicate, timeout: float) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for event in log_events(log):
            if predicate(event):
                return event
        time.sleep(0.05)
    raise AssertionError(f"no matching event in {log} within {timeout} s:\n{log.read_text()[-3000:]}")


def test_killed_agent_is_seen_leaving_within_3_s_and_sigterm_lands(tmp_path: Path, swarm_ports: SwarmPorts) -> None:
    """Two agents started by hand next to `swarm sim` and `swarm cameras`, as the README's "by hand" section does:
    each maps from its simulated camera's stream (the agents are given the mission volume, never the world)."""
    p = swarm_ports
    sensors = f"tcp/127.0.0.1:{p.bus_base + 10}"
    ports = [
        "--set",
        f"sim.vehicle_base_port={p.vehicle_base}",
        "--set",
        f"sim.gcs_base_port={p.gcs_base}",
        "--set",
        f'camera.stream.connect=["{sensors}"]',
    ]
    procs: list[subprocess.Popen] = []
    logs = {name: tmp_path / f"{name}.log" for name in ("sim", "cameras", "agent-1", "agent-2")}
    try:
        procs.append(
            subprocess.Popen(
                swarm_cmd("sim", "--world", "box", "--vehicles", "2", *ports),
                stdout=logs["sim"].open("w"),
                stderr=subprocess.STDOUT,
            )
        )
        volume = _wait_for_line(logs["sim"], "(agent: swarm agent --id 1 ", 30).split("--set '")[1].rstrip("')")
        assert volume.startswith("mission.volume={min=[0, 0, "), volume
        procs.append(
            subprocess.Popen(
                swarm_cmd("cameras", "--world", "box", "--vehicles", "2", *ports),
                stdout=logs["cameras"].open("w"),
                stderr=subprocess.STDOUT,
            )
        )
        for k in (1, 2):
            bus = [
                "--set",
                f'bus.listen=["tcp/127.0.0.1:{p.bus_base + k}"]',
                "--set",
                f'bus.connect=["tcp/127.0.0.1:{p.bus_base + 1}"]' if k == 2 else "bus.connect=[]",
            ]
            procs.append(
                subprocess.Popen(
                    swarm_cmd(
                        "agent",
                        "--id",
                        str(k),
                        "--autopilot",
                        f"udpin://127.0.0.1:{p.gcs_base + k - 1}",
                        "--set",
                        "agent.hover_s=120",
                        "--set",
                        "agent.px4_params=set",
                        "--set",
                        "explore.strategy=scripted",
                        "--set",
                        volume,
                        "--set",
                        "mission.world=/nonexistent/world.ply",
                        "--set",
                        f"agent.out_dir={tmp_path}",
                        *ports,
                        *bus,
                    ),
                    stdout=logs[f"agent-{k}"].open("w"),
                    stderr=subprocess.STDOUT,
                )
            )
        sim, cameras, agent1, agent2 = procs
        _wait_for(logs["agent-1"], lambda e: e["event"] == "peer_joined" and e["peer"] == 2, 60)
        _wait_for(logs["agent-2"], lambda e: e["event"] == "peer_joined" and e["peer"] == 1, 60)
        _wait_for(logs["agent-1"], lambda e: e["event"] == "phase" and e["phase"] == Phase.HOVERING, 60)
        assert agent2.poll() is None

        killed_at = time.time()
        agent2.send_signal(signal.SIGKILL)
        left = _wait_for(logs["agent-1"], lambda e: e["event"] == "peer_left" and e["peer"] == 2, 10)
        assert left["t"] - killed_at < 3.0, f"agent 1 saw agent 2 leave after {left['t'] - killed_at:.2f} s"

        agent1.send_signal(signal.SIGTERM)
        try:
            code = agent1.wait(timeout=60)
        except subprocess.TimeoutExpired:
            agent1.send_signal(signal.SIGUSR1)  # the agent dumps every thread's stack into its log
            time.sleep(1.0)
            raise AssertionError(
                f"agent 1 did not exit after SIGTERM:\n{logs['agent-1'].read_text()[-6000:]}"
            ) from None
        assert code == 0
        events = log_events(logs["agent-1"])
        phases = [e["phase"] for e in events if e["event"] == "phase"]
        assert phases[-2:] == [Phase.LANDING, Phase.LANDED], phases
        summary = json.loads((tmp_path / "agent-1.json").read_text())
        assert summary["frames"] > 10 and summary["sensor_stream"]["frames"] >= summary["frames"], summary
    finally:
        kill_all(procs)


def _wait_for_line(log: Path, needle: str, timeout: float) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for line in log.read_text().splitlines():
            if needle in line:
                return line
        time.sleep(0.05)
    raise AssertionError(f"no line with {needle!r} in {log} within {timeout} s:\n{log.read_text()[-3000:]}")


def test_sigterm_ends_swarm_run_as_ctrl_c_does_landing_and_cleaning_up(tmp_path: Path, swarm_ports: SwarmPorts) -> None:
    out = tmp_path / "run"
    cmd = swarm_cmd("run", "--no-live", "--out", str(out), *swarm_ports.overrides(), "--world", "box", "--drones", "1")
    run = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        log = out / "logs" / "agent-1.log"
        deadline = time.monotonic() + 60
        while not (log.is_file() and any(e.get("phase") == Phase.FLYING for e in log_events(log))):
            assert run.poll() is None and time.monotonic() < deadline, "the drone never flew"
            time.sleep(0.2)
        run.send_signal(signal.SIGTERM)
        assert run.wait(timeout=90) != 0
        report = json.loads((out / "report.json").read_text())
        assert (report["status"], report["reason"]) == ("failed", "interrupted")
        assert report["agents"][0]["phase"] == Phase.LANDED, report["agents"]
        assert not processes_mentioning(str(out)), "swarm run left processes behind"
    finally:
        kill_all([run])
