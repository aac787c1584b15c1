"""Sensor streams to a ROS 2 MCAP bag and back: a recorded flight that rosbags reads, `swarm map` maps it onto the
world's surfaces, and every bag it cannot use is one clear line."""

from __future__ import annotations

import json
import math
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from swarm.agent.bagmap import map_bags
from swarm.config import load_config
from swarm.errors import SwarmError
from swarm.sensing import messages as m
from swarm.sensing.bags import BagRecorder
from swarm.sensing.frames import camera_mount, camera_to_world
from swarm.sim.camera import DepthCamera
from swarm.sim.sensors import body_pose
from swarm.sim.worlds import load_world
from tests.helpers import SwarmPorts, swarm_cmd

POSE, INFO, DEPTH = "/odom", "/camera/depth/camera_info", "/camera/depth/image_rect_raw"


def _record(path: Path, seconds: float = 5.0, with_depth: bool = True, extra_image_topic: bool = False) -> None:
    """A tilting flight along the office's lobby: odometry at 50 Hz, depth and camera info at 10 Hz."""
    config = load_config()
    world = load_world("office")
    camera = DepthCamera(world, config.camera)
    K = np.array(camera.intrinsics)
    K[0, 2] -= 0.5
    K[1, 2] -= 0.5
    info = m.Intrinsics(config.camera.width, config.camera.height, K)
    bag = BagRecorder(path)
    try:
        for i in range(int(seconds * 50)):
            t = 100.0 + i / 50
            s = i / (seconds * 50)
            pose = body_pose(
                t,
                np.array([3.0 + 4.0 * s, 10.0, 1.5]),
                math.radians(8) * math.cos(2 * t),
                math.radians(12) * math.sin(3 * t),
                math.radians(90 + 180 * s),
            )
            bag.write(POSE, m.ODOMETRY, int(t * 1e9), m.serialize(m.odometry_message(pose)))
            if i % 5 == 0 and with_depth:
                depth = camera.render(camera_to_world(pose, camera_mount(config.camera)))
                bag.write(INFO, m.CAMERA_INFO, int(t * 1e9), m.serialize(m.camera_info_message(t, info)))
                for topic in (DEPTH, "/other/depth")[: 1 + extra_image_topic]:
                    bag.write(topic, m.IMAGE, int(t * 1e9), m.serialize(m.image_message(t, depth, encoding="16UC1")))
    finally:
        bag.close()


def test_a_recorded_flight_reads_back_and_maps_onto_the_world(tmp_path: Path) -> None:
    bag = tmp_path / "flight"
    _record(bag)
    with AnyReader([bag]) as reader:  # what ros2 bag, Foxglove and Rerun see
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts == {POSE: 250, INFO: 50, DEPTH: 50}
    report = map_bags(load_config(), [bag], tmp_path / "map", {})
    assert report["bags"][0]["frames"] == 50 and report["bags"][0]["dropped"] == {}
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(tmp_path / "map" / "map.ply"))
    vertices = np.asarray(mesh.vertices)
    assert len(vertices) > 1000 and (tmp_path / "map" / "report.json").exists()
    on_surfaces = float(np.mean(load_world("office").distance(vertices) <= 0.2))
    print(f"mesh vertices within 0.2 m of the world: {on_surfaces:.3f}")
    assert on_surfaces >= 0.95
    assert list((tmp_path / "map" / "patches").glob("1.1.*.patch"))


def _as_ros1(mcap: Path, bag: Path) -> None:
    """The recording rewritten as a ROS 1 bag, as `rosbag record` would have written it (ROS 1 definitions, whose
    CameraInfo spells K, D, R, P in capitals and whose Header has a seq)."""
    from rosbags.rosbag1 import Writer as Ros1Writer
    from rosbags.typesys import Stores, get_typestore

    ros1 = get_typestore(Stores.ROS1_NOETIC)
    with AnyReader([mcap], default_typestore=m.typestore()) as reader, Ros1Writer(bag) as writer:
        out = {c.topic: writer.add_connection(c.topic, c.msgtype, typestore=ros1) for c in reader.connections}
        for connection, t_ns, raw in reader.messages():
            message = m.convert_message(reader.deserialize(raw, connection.msgtype), connection.msgtype, ros1)
            writer.write(out[connection.topic], t_ns, ros1.serialize_ros1(message, connection.msgtype))


def test_a_ros1_bag_maps_as_the_ros2_recording_of_the_same_flight_does(tmp_path: Path) -> None:
    mcap, bag = tmp_path / "flight", tmp_path / "flight.bag"
    _record(mcap, seconds=2.0)
    _as_ros1(mcap, bag)
    with AnyReader([bag]) as reader:
        assert not reader.is2 and {c.topic: c.msgcount for c in reader.connections} == {POSE: 100, INFO: 20, DEPTH: 20}
    ros2 = map_bags(load_config(), [mcap], tmp_path / "map2", {})
    ros1 = map_bags(load_config(), [bag], tmp_path / "map1", {})
    assert ros1["bags"][0]["frames"] == ros2["bags"][0]["frames"] == 20 and ros1["bags"][0]["dropped"] == {}
    assert ros1["fused_digest"] == ros2["fused_digest"], "the same messages must give the same map"


@pytest.mark.parametrize(
    ("kwargs", "topics", "says"),
    [
        ({"with_depth": False}, {}, "has no depth image topic"),
        ({"extra_image_topic": True}, {}, "several depth image topics .* --depth-topic"),
        ({}, {"pose": "/nope"}, "has no topic /nope"),
        ({}, {"depth": POSE}, "is nav_msgs/msg/Odometry, not sensor_msgs/msg/Image"),
    ],
)
def test_a_bag_that_cannot_be_mapped_is_one_clear_error(tmp_path: Path, kwargs: dict, topics: dict, says: str) -> None:
    bag = tmp_path / "bag"
    _record(bag, seconds=0.2, **kwargs)
    with pytest.raises(SwarmError, match=says):
        map_bags(load_config(), [bag], tmp_path / "map", topics)


@pytest.mark.sim
def test_swarm_map_on_a_missing_bag_is_one_line_and_a_non_zero_exit(tmp_path: Path) -> None:
    done = subprocess.run(
        swarm_cmd("map", str(tmp_path / "missing"), "--out", str(tmp_path / "o")),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode != 0
    assert len(done.stderr.strip().splitlines()) == 1 and "does not exist" in done.stderr


def test_a_bag_replayed_as_the_camera_offers_every_frame_at_its_pace_and_counts_any_not_taken(tmp_path: Path) -> None:
    from swarm.sensing.replay_source import BagReplaySource

    bag = tmp_path / "flight"
    _record(bag, seconds=2.0)
    config = load_config()
    source = BagReplaySource(bag, config.camera.stream, camera_mount(config.camera), speed=1.0)
    frames = []
    started = time.monotonic()
    source.start()
    try:
        while True:
            finished = source.finished.is_set()  # before the wait: then every frame was offered before it
            frame = source.wait_frame(0.5)
            if frame is None and finished:
                break
            frames.append(frame)
            assert time.monotonic() - started < 20.0
    finally:
        source.close()
    got = [f for f in frames if f is not None]
    # 2 s at 10 Hz: every frame taken, or superseded before the consumer came back and counted (a live camera's
    # semantics; on an idle machine none is)
    assert len(got) + source.counters()["not_taken"] == 20 and len(got) >= 10
    assert time.monotonic() - started >= 1.8  # played at the recorded pace, not at once
    assert [f.t for f in got] == sorted(f.t for f in got)


def test_replaying_a_bag_without_depth_is_one_clear_error(tmp_path: Path) -> None:
    from swarm.sensing.replay_source import BagReplaySource

    bag = tmp_path / "no-depth"
    _record(bag, seconds=0.2, with_depth=False)
    config = load_config()
    with pytest.raises(SwarmError, match="camera.replay_bag: bag .* has no depth image topic"):
        BagReplaySource(bag, config.camera.stream, camera_mount(config.camera)).start()


@pytest.mark.sim
def test_an_agent_replaying_a_bag_without_depth_exits_with_one_line_before_it_opens_bus_or_autopilot(
    tmp_path: Path, swarm_ports: SwarmPorts
) -> None:
    bag = tmp_path / "no-depth"
    _record(bag, seconds=0.2, with_depth=False)
    config = tmp_path / "agent.toml"
    config.write_text(
        f"""
[mission]
volume = {{ min = [0.0, 0.0, 0.0], max = [20.0, 20.0, 3.0] }}
[camera]
source = "replay"
replay_bag = "{bag}"
[agent]
autopilot = "udpin://127.0.0.1:{swarm_ports.vehicle_base}"
[bus]
base_port = {swarm_ports.bus_base}
"""
    )
    started = time.monotonic()
    done = subprocess.run(swarm_cmd("agent", "--config", str(config)), capture_output=True, text=True, timeout=60)
    assert done.returncode != 0
    assert done.stderr.strip().splitlines() == [
        f"swarm agent: error: camera.replay_bag: bag {bag} has no depth image topic (sensor_msgs/msg/Image)"
    ]
    # refused before anything that flies: nothing logged after `starting` (no bus, no autopilot connection)
    assert [json.loads(line)["event"] for line in done.stdout.splitlines()] == ["starting"]
    assert time.monotonic() - started < 15.0  # less than the autopilot's connect timeout: it was never waited for
