"""Agents that map from sensor streams (issue 22): a real 3-drone `swarm run` with the default camera ("sim": the
simulator publishes each vehicle's odometry (with its tilt), `swarm cameras` renders and publishes each depth
camera as ROS 2 messages in the rmw_zenoh key layout, and the agents, which are given no world at all (their
config names a file that does not exist), map from those streams and explore the box world to the end."""

from __future__ import annotations

import signal
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from swarm.agent.bagmap import map_bags
from swarm.bus.phase import Phase
from swarm.config import load_config
from swarm.mission.report import read_observer_status
from swarm.mission.run import NO_WORLD_FOR_AGENTS, RunState, run_mission
from swarm.sim.worlds import load_world
from tests.helpers import SwarmPorts, processes_mentioning

pytestmark = [pytest.mark.timeout(300), pytest.mark.mission]


def test_agents_given_no_world_and_no_gps_map_from_the_simulated_cameras_streams_and_complete(
    tmp_path: Path, swarm_ports: SwarmPorts
) -> None:
    """As indoors on real vehicles: no world for the agents, and vehicles without GPS (no global position, no home
    position, no Hold), each agent flying in its vehicle's local frame, whose origin is not where it takes off."""
    out = tmp_path / "run"
    config = load_config(
        overrides={
            "mission.world": "box",
            "mission.out": str(out),
            "mission.drones": 3,
            "mission.max_time_s": 240.0,
            "mission.record": True,  # camera.source is "sim", the default: the simulated cameras, streamed
            "sim.gps": False,
            "sim.local_origin_offset": [0.8, -0.6, 0.0],
            **swarm_ports.settings(),
        }
    )
    report = run_mission(config, live=False)
    assert report["status"] == "complete", report["reason"]
    assert report["explored_fraction"] >= 0.95
    assert report["collisions"] == 0, report["collision_events"]
    assert not (out / "config" / NO_WORLD_FOR_AGENTS).exists()
    spawns = load_config(out / "config" / "sim.toml").sim.spawns
    for k in range(1, 4):
        agent_config = load_config(out / "config" / f"agent-{k}.toml")
        assert agent_config.mission.world.endswith(NO_WORLD_FOR_AGENTS) and agent_config.mission.volume is not None
        assert agent_config.camera.stream.depth_topic.startswith(f"/drone{k}/")
        assert agent_config.agent.frame == "local"
        assert agent_config.agent.local_origin == pytest.approx(np.add(spawns[k - 1], (0.8, -0.6, 0.0)))
        log = (out / "logs" / f"agent-{k}.log").read_text()
        assert "not possible" not in log and "Failsafe" not in log  # never asked for Hold, never failed safe
    for agent in report["agents"]:
        stream = agent["sensor_stream"]
        assert agent["exit_code"] == 0 and agent["frames"] > 100, agent
        # every frame the camera driver published reached the agent whole, with a pose: only images that came
        # before the first camera info or the first pose, while the subscriptions were being matched, are dropped
        # (the driver sends camera info with every image, so this happens only at start-up: at most a second of the
        # 10 Hz stream; 3 on a fresh 2-core machine)
        starting = ("image before camera info", "pose early")
        assert all(stream.get(reason, 0) <= 10 for reason in starting), stream
        others = {
            k: v
            for k, v in stream.items()
            if k not in ("frames", "not_taken", "pixels_masked_as_peers", "camera_silences", *starting)
        }
        assert not others, stream
        assert stream["camera_silences"] == 0, stream
        assert agent["frame_rate_hz"] >= 8.0, agent
    # the cameras see the other drones, and the agents keep them out of their maps
    assert sum(a["sensor_stream"]["pixels_masked_as_peers"] for a in report["agents"]) > 0
    assert "published" in (out / "logs" / "cameras.log").read_text()
    assert not processes_mentioning(str(out)), "swarm run left processes behind"
    # no phantom obstacles along the drones' paths: the cameras saw the drones, the maps do not have them
    phantoms = report["phantoms"]
    print(f"phantom check: {phantoms}")
    assert phantoms["vertices"] > 1000 and phantoms["phantoms"] == 0, phantoms
    # the bags the agents recorded map offline onto the world as the live run did
    bags = [out / "bags" / f"agent-{k}" for k in range(1, 4)]
    offline = map_bags(load_config(overrides={"mission.world": "box"}), bags, tmp_path / "offline", {})
    assert [b["frames"] for b in offline["bags"]] == [a["sensor_stream"]["frames"] for a in report["agents"]]
    world = load_world("box")
    for mesh in (out / "map.ply", tmp_path / "offline" / "map.ply"):
        vertices = np.asarray(o3d.io.read_triangle_mesh(str(mesh)).vertices)
        on_surfaces = float(np.mean(world.distance(vertices) <= 0.2))
        print(f"{mesh}: {len(vertices)} vertices, {on_surfaces:.3f} within 0.2 m of the world")
        assert on_surfaces >= 0.95


def test_a_mission_whose_cameras_die_fails_at_once_saying_so_and_lands(tmp_path: Path, swarm_ports: SwarmPorts) -> None:
    out = tmp_path / "run"
    config = load_config(
        overrides={
            "mission.world": "box",
            "mission.out": str(out),
            "mission.drones": 1,
            "mission.max_time_s": 120.0,
            **swarm_ports.settings(),
        }
    )
    killed: list[float] = []

    def kill_cameras_once_flying(state: RunState) -> None:
        observer = read_observer_status(out)
        agents = observer.agents if observer is not None else {}
        if not killed and state.cameras is not None and any(a.phase == Phase.FLYING for a in agents.values()):
            state.cameras.signal(signal.SIGKILL)
            killed.append(1.0)

    report = run_mission(config, live=False, on_tick=kill_cameras_once_flying)
    assert killed, "the drone never flew"
    assert report["status"] == "failed" and report["reason"].startswith("cameras died"), report["reason"]
    assert report["duration_s"] < 60.0
    assert not processes_mentioning(str(out)), "swarm run left processes behind"
