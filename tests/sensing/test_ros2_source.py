"""camera.source = "ros2": a real ROS 2 node (rclpy over Fast DDS, the PyPI wheels, in a process of its own,
discovery kept on this host) publishes depth, camera info and odometry rendered from a world along a tilting
flight; `Ros2SensorSource`, which never sees the world, gives frames from which the map lies on the world."""

from __future__ import annotations

import os
import random
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from swarm.config import load_config
from swarm.patches.mapper import Mapper
from swarm.sensing.frames import camera_mount
from swarm.sensing.ros2_source import Ros2SensorSource
from swarm.sim.worlds import load_world, mission_volume

NODE = Path(__file__).with_name("ros2_camera_node.py")


@pytest.mark.ros2
def test_frames_from_a_ros2_node_map_onto_the_world(monkeypatch: pytest.MonkeyPatch) -> None:
    domain = str(random.randrange(1, 100))  # apart from any other test's ROS graph
    for name, value in (("ROS_DOMAIN_ID", domain), ("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")):
        monkeypatch.setenv(name, value)
    config = load_config()
    source = Ros2SensorSource(config.camera.stream, camera_mount(config.camera))
    root = Path(__file__).resolve().parents[2]
    node = subprocess.Popen(
        [sys.executable, str(NODE), "8"],
        cwd=root,
        env={**os.environ, "PYTHONPATH": str(root)},
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    frames = []
    try:
        source.start()
        deadline = time.monotonic() + 30.0
        while node.poll() is None and time.monotonic() < deadline:
            frame = source.wait_frame(0.5)
            if frame is not None:
                frames.append(frame)
    finally:
        source.close()
        node.kill()
        output = node.communicate()[0]
    assert len(frames) >= 30, (source.counters(), output[-2000:])
    world = load_world("office")
    mapper = Mapper(config.mapping, 1, 1, mission_volume(world, None))
    for frame in frames:
        mapper.integrate(frame.depth, frame.K, frame.T_world_cam, frame.t, config.camera.max_range_m)
    mapper.seal()
    vertices, _ = mapper.fused.mesh()
    on_surfaces = float(np.mean(world.distance(vertices) <= 0.2))
    print(f"{len(frames)} frames, counters {source.counters()}, {on_surfaces:.3f} of vertices within 0.2 m")
    assert len(vertices) > 1000 and on_surfaces >= 0.95


def test_without_the_ros2_extra_the_source_is_one_line_that_says_what_to_install(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from swarm.errors import SwarmError

    monkeypatch.setitem(sys.modules, "rclpy", None)  # as if the wheels were not installed
    config = load_config()
    with pytest.raises(SwarmError, match=r"pip install 'swarm\[ros2\]'"):
        Ros2SensorSource(config.camera.stream, camera_mount(config.camera)).start()
