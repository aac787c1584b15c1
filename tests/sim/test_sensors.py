"""The simulated vehicles' sensors as ROS 2 streams: the PX4 attitude becomes a ROS pose; the cameras see each
other (a drone-sized return where a peer is); and a map built from the camera driver's images, heard through real
Zenoh sessions by a side that never loads the world, lies on the world's surfaces along a flight that tilts (and
would not, were the attitude ignored)."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
import zenoh
from scipy.spatial.transform import Rotation

from swarm.config import CameraSettings, load_config
from swarm.patches.mapper import Mapper
from swarm.sensing import messages as m
from swarm.sensing.frames import camera_mount, camera_to_world
from swarm.sensing.peers import pixel_rays
from swarm.sensing.zenoh_source import ZenohSensorSource, session_config
from swarm.sim.camera import DepthCamera
from swarm.sim.collisions import GROUND_GAP_M
from swarm.sim.sensors import CameraDriver, StreamPublisher, body_pose, render_with_peers
from swarm.sim.worlds import World, boxes_to_mesh, load_world, mission_volume
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


def test_the_pose_is_px4s_attitude_turned_into_enu_and_flu_at_any_attitude() -> None:
    enu_from_ned = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    frd_from_flu = np.diag([1.0, -1.0, -1.0])
    for roll, pitch, yaw in np.random.default_rng(5).uniform(-math.pi, math.pi, (50, 3)) * [0.5, 0.45, 1.0]:
        pose = body_pose(1.0, np.array([1.0, 2.0, 3.0]), roll, pitch, yaw)
        ned_from_frd = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
        assert np.linalg.norm(pose.orientation) == pytest.approx(1.0)
        np.testing.assert_allclose(_axes(pose), enu_from_ned @ ned_from_frd @ frd_from_flu, atol=1e-12)


def _wall_at_x(d: float) -> World:
    vertices, triangles = boxes_to_mesh([((d, -50.0, -50.0), (d + 0.2, 50.0, 50.0))], exact=1)
    return World("wall", vertices, triangles, (0.0, 0.0, 0.0))


def test_a_peer_in_front_of_the_camera_is_a_drone_sized_return_and_without_it_the_world_alone() -> None:
    settings, radius = CameraSettings(), 0.2
    camera = DepthCamera(_wall_at_x(5.0), settings)
    T = camera.pose((0.0, 0.0, 1.0), 0.0)  # looking along +x at the wall 5 m away
    rays = pixel_rays(np.asarray(camera.intrinsics), settings.height, settings.width)
    world = camera.render(T)
    assert np.array_equal(render_with_peers(world.copy(), rays, T, [], radius, settings), world)
    peer = np.array([2.0, 0.0, 1.0 - radius - GROUND_GAP_M])  # its body's centre on the optical axis, 2 m out
    seen = render_with_peers(world.copy(), rays, T, [peer], radius, settings)
    drone = seen != world
    assert drone[settings.height // 2, settings.width // 2]
    assert float(seen[drone].min()) == pytest.approx(2.0 - radius, abs=0.01)
    assert np.all(seen[drone] < 2.0 + radius)
    rows, cols = np.nonzero(drone)
    fx = camera.intrinsics[0][0]
    for pixels in (cols.max() - cols.min() + 1, rows.max() - rows.min() + 1):
        assert pixels / fx * 2.0 == pytest.approx(2 * radius, abs=0.05)  # 0.4 m across at 2 m, both ways
    behind_the_wall = peer + np.array([4.0, 0.0, 0.0])  # its near side 0.8 m behind the wall
    assert np.array_equal(render_with_peers(world.copy(), rays, T, [behind_the_wall], radius, settings), world)


class _Published:
    """A publisher that keeps what it is given (the driver's publishing without Zenoh)."""

    def __init__(self) -> None:
        self.messages: dict[str, object] = {}

    def put(self, topic: str, message: object) -> None:
        self.messages[topic] = message


def test_the_camera_driver_publishes_the_other_drones_in_each_depth_image() -> None:
    """Drone 1 hovers facing east with drone 2 two metres ahead: its image has a return nearer than the wall."""
    settings = CameraSettings()
    driver = CameraDriver(_wall_at_x(5.0), settings, [1, 2], drone_radius_m=0.2)
    driver._poses = {1: body_pose(10.0, np.array([0.0, 0.0, 1.0]), 0.0, 0.0, math.radians(90))}
    nearest = []
    for peer in (None, body_pose(10.0, np.array([2.0, 0.0, 0.8]), 0.0, 0.0, 0.0)):
        if peer is not None:
            driver._poses[2] = peer
        published = _Published()
        driver._publish(1, published)  # type: ignore[arg-type]
        _, depth = m.depth_of(published.messages[driver.streams[1].depth_topic])
        nearest.append(float(depth[depth > 0].min()))
    assert nearest[0] > 4.5 and 1.5 < nearest[1] < 2.0  # the wall alone; then drone 2 in front of it


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
