"""The simulated vehicles' sensors as ROS 2 streams: the PX4 attitude becomes a ROS pose, and a map built from
the camera driver's images, heard through real Zenoh sessions by a side that never loads the world, lies on the
world's surfaces along a flight that tilts (and would not, were the attitude ignored)."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
import zenoh
from scipy.spatial.transform import Rotation

from swarm.config import load_config
from swarm.patches.mapper import Mapper
from swarm.sensing import messages as m
from swarm.sensing.frames import camera_mount, camera_to_world
from swarm.sensing.zenoh_source import ZenohSensorSource, session_config
from swarm.sim.sensors import CameraDriver, StreamPublisher, body_pose
from swarm.sim.worlds import load_world, mission_volume
from tests.helpers import loopback_zenoh
from tests.sensing.flight import flight


def _axes(pose: m.Pose) -> np.ndarray:
    return Rotation.from_quat(pose.orientation).as_matrix()


def test_px4_attitude_becomes_an_enu_flu_pose() -> None:
    level_north = _axes(body_pose(0.0, np.zeros(3), 0.0, 0.0, 0.0))
    assert np.allclose(level_north[:, 0], [0, 1, 0]) and np.allclose(level_north[:, 2], [0, 0, 1])
    nose_up_east = _axes(body_pose(0.0, np.zeros(3), 0.0, math.radians(10), math.radians(90)))
    assert np.allclose(nose_up_east[:, 0], [math.cos(math.radians(10)), 0, math.sin(math.radians(10))])
    right_wing_down = _axes(body_pose(0.0, np.zeros(3), math.radians(10), 0.0, 0.0))
    assert right_wing_down[2, 1] == pytest.approx(math.sin(math.radians(10)))  # the left side goes up


@pytest.fixture
def router() -> Iterator[str]:
    """A Zenoh router on loopback, as rmw_zenohd is on a robot."""
    with loopback_zenoh("router") as (_, endpoint):
        yield endpoint


@pytest.mark.bus
def test_a_map_from_the_camera_driver_through_zenoh_lies_on_the_world_and_needs_the_attitude(router: str) -> None:
    config = load_config(overrides={"camera.stream.connect": [router]})
    world = load_world("office")
    driver = CameraDriver(world, config.camera, [1])
    stream = config.camera.stream.under_vehicle(1)
    source = ZenohSensorSource(stream, camera_mount(config.camera))  # the agent's side: no world
    stop = threading.Event()
    threads = [threading.Thread(target=driver.run, args=(stop,), daemon=True)]
    pose_side = zenoh.open(session_config(stream))
    poses = StreamPublisher(pose_side, stream, gid=1)
    frames, level = [], []
    try:
        source.start()
        threads[0].start()
        started = time.time()
        while time.time() - started < 8.0:  # the autopilot bridge's odometry at 50 Hz
            t = time.time()
            position, roll, pitch, yaw = flight(t - started)
            poses.put(stream.pose_topic, m.odometry_message(body_pose(t, position, roll, pitch, yaw)))
            frame = source.wait_frame(0.02)
            if frame is not None:
                frames.append(frame)
                position, _, _, yaw = flight(frame.t - started)
                level.append(body_pose(frame.t, position, 0.0, 0.0, yaw))
    finally:
        stop.set()
        threads[0].join(timeout=10)
        source.close()
        pose_side.close()
    assert len(frames) >= 40 and driver.published[1] >= len(frames)
    assert source.counters().get("bad image", 0) == 0

    def fraction_on_surfaces(use_attitude: bool) -> float:
        mapper = Mapper(config.mapping, 1, 1, mission_volume(world, None))
        for frame, flat in zip(frames, level):
            T = frame.T_world_cam
            if not use_attitude:  # the same images at position and yaw only
                T = camera_to_world(flat, camera_mount(config.camera))
            mapper.integrate(frame.depth, frame.K, T, frame.t, config.camera.max_range_m)
        mapper.seal()
        vertices, _ = mapper.fused.mesh()
        assert len(vertices) > 1000
        return float(np.mean(world.distance(vertices) <= 0.2))

    with_attitude, without = fraction_on_surfaces(True), fraction_on_surfaces(False)
    print(f"mesh vertices within 0.2 m of the world: {with_attitude:.3f} with the attitude, {without:.3f} without")
    assert with_attitude >= 0.95
    assert without < 0.9
