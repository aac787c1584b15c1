"""The simulated vehicles' sensors as a robot's ROS 2 side publishes them: each vehicle's pose (odometry, what a
VIO or the autopilot bridge gives) and each vehicle's depth camera (image and camera info, what a camera driver
gives), on Zenoh in the key layout of `camera.stream` (rmw_zenoh by default) under the namespace /drone<k>.

`CameraDriver` hears each vehicle's odometry and, at `camera.rate_hz`, publishes a depth image rendered from the
world at that pose, times the camera's mount, stamped with the pose's stamp: the agent, which never loads the
world, interpolates its own copy of the odometry at that stamp and gets the very pose the image was rendered at.
"""

from __future__ import annotations

import math
import signal
import struct
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import zenoh

from swarm.bus.session import zenoh_error_text
from swarm.config import CameraSettings, SensorStreamSettings, SwarmConfig
from swarm.errors import SwarmError
from swarm.sensing import messages as m
from swarm.sensing.frames import camera_mount, camera_to_world
from swarm.sensing.peers import pixel_rays, sphere_depth
from swarm.sensing.stream import POSE_TYPES
from swarm.sensing.zenoh_source import session_config, topic_key
from swarm.sim.camera import DepthCamera
from swarm.sim.collisions import GROUND_GAP_M
from swarm.sim.kinematics import Body, tilt
from swarm.sim.worlds import World, load_world

# what a camera driver hands each frame it publishes to: vehicle id, stamp (unix s), T_world_cam (4x4, optical
# frame), depth (H, W) in metres with 0 for no return
FrameHook = Callable[[int, float, np.ndarray, np.ndarray], None]

# ENU <- NED and FRD <- FLU: the same axes swapped and flipped (PX4's attitude is NED / FRD, ROS's ENU / FLU)
_ENU_FROM_NED_Q = (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0)  # half a turn about (x + y) / sqrt(2)
_FRD_FROM_FLU_Q = (1.0, 0.0, 0.0, 0.0)  # half a turn about x


def body_pose(t: float, position_enu: np.ndarray, roll: float, pitch: float, yaw_ned: float) -> m.Pose:
    """The ROS pose (ENU world, FLU body) of a vehicle with PX4 attitude roll, pitch, yaw (rad, FRD body in NED).

    In closed form (the simulator publishes every vehicle's pose at sim.odometry_hz; scipy's Rotation took a
    quarter of its time): q(ENU<-FLU) = q(ENU<-NED) q(NED<-FRD) q(FRD<-FLU), quaternions (x, y, z, w)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw_ned / 2), math.sin(yaw_ned / 2)
    frd = (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )
    quat = _hamilton(_hamilton(_ENU_FROM_NED_Q, frd), _FRD_FROM_FLU_Q)
    return m.Pose(t, np.asarray(position_enu, dtype=np.float64).copy(), np.array(quat))


def _hamilton(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float, float]:
    """The product a b of quaternions (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def render_with_peers(
    depth: np.ndarray,
    rays: np.ndarray,
    T_world_cam: np.ndarray,
    peers: Sequence[np.ndarray | Sequence[float]],
    drone_radius_m: float,
    camera: CameraSettings,
) -> np.ndarray:
    """`depth`, the world's z-depth image (0 = no return), with the other drones in it as a real camera sees them:
    each a sphere of `drone_radius_m` just above its position (as the collision check has it), drawn where it is
    nearer than the world (or where the world gave no return) and within the camera's range. `rays` are
    `pixel_rays` of the camera's intrinsics. Changes `depth` in place and returns it."""
    if len(peers) == 0:
        return depth
    centres = np.asarray(peers, dtype=np.float64).reshape(-1, 3) + np.array([0.0, 0.0, drone_radius_m + GROUND_GAP_M])
    drones = sphere_depth(rays, T_world_cam, centres, drone_radius_m).astype(np.float32)
    seen = (drones >= camera.min_range_m) & (drones <= camera.max_range_m) & ((depth <= 0) | (drones < depth))
    depth[seen] = drones[seen]
    return depth


class StreamPublisher:
    """Puts ROS 2 messages on Zenoh under the keys a ROS 2 node would (rmw_zenoh: with the type hash and an
    attachment of sequence number, source time and GID, as rmw_zenoh sends them)."""

    def __init__(self, session: zenoh.Session, settings: SensorStreamSettings, gid: int) -> None:
        self.session, self.settings = session, settings
        self._gid = gid.to_bytes(16, "little")
        self._seq = 0
        self._keys: dict[tuple[str, str], str] = {}

    def _key(self, topic: str, msgtype: str) -> str:
        """The Zenoh key of a topic and type, made once (the type hash took an eighth of the simulator's time)."""
        key = self._keys.get((topic, msgtype))
        if key is None:
            key = topic_key(self.settings, topic, msgtype)
            if self.settings.layout == "rmw_zenoh":
                key = key.replace("*", m.typestore().hash_rihs01(msgtype))
            self._keys[(topic, msgtype)] = key
        return key

    def put(self, topic: str, message: Any) -> None:
        key = self._key(topic, message.__msgtype__)
        self._seq += 1
        attachment = struct.pack("<qqB", self._seq, time.time_ns(), 16) + self._gid
        self.session.put(key, m.serialize(message), attachment=attachment)


class CameraDriver:
    def __init__(
        self,
        world: World,
        camera: CameraSettings,
        vehicle_ids: list[int],
        seed: int = 0,
        log: Callable[[str], None] | None = None,
        drone_radius_m: float = 0.2,
        on_frame: FrameHook | None = None,
    ) -> None:
        self.camera_settings = camera
        self.on_frame = on_frame
        self.drone_radius_m = drone_radius_m
        self.streams = {k: camera.stream.under_vehicle(k) for k in vehicle_ids}
        self.cameras = {k: DepthCamera(world, camera, seed * 1000 + k) for k in vehicle_ids}
        self.mount = camera_mount(camera)
        self.intrinsics = m.Intrinsics(camera.width, camera.height, self._ros_K())
        self._rays = pixel_rays(next(iter(self.cameras.values())).intrinsics, camera.height, camera.width)
        self._poses: dict[int, m.Pose] = {}
        self._lock = threading.Lock()
        self.published = {k: 0 for k in vehicle_ids}
        self.render_s = 0.0
        self.log = log or (lambda text: None)

    def _ros_K(self) -> np.ndarray:
        """The rendering camera's K in the ROS convention (pixel centres at integers)."""
        K = np.array(next(iter(self.cameras.values())).intrinsics, dtype=np.float64)
        K[0, 2] -= 0.5
        K[1, 2] -= 0.5
        return K

    def run(self, stop: threading.Event) -> None:
        """Subscribe to every vehicle's odometry and publish its camera at camera.rate_hz until `stop`."""
        base = self.camera_settings.stream
        session = zenoh.open(session_config(base))
        try:
            subscribers = [
                session.declare_subscriber(topic_key(s, s.pose_topic, POSE_TYPES[s.pose_type]), self._on_pose(k))
                for k, s in self.streams.items()
            ]
            publishers = {k: StreamPublisher(session, s, gid=1000 + k) for k, s in self.streams.items()}
            period = 1.0 / self.camera_settings.rate_hz
            next_tick = time.monotonic()
            while not stop.is_set():
                for k, publisher in publishers.items():
                    self._publish(k, publisher)
                next_tick += period
                delay = next_tick - time.monotonic()
                if delay < 0:
                    next_tick += math.ceil(-delay / period) * period
                    delay = next_tick - time.monotonic()
                stop.wait(max(delay, 0.0))
            for subscriber in subscribers:
                subscriber.undeclare()
        finally:
            session.close()

    def _on_pose(self, vehicle_id: int) -> Callable[[zenoh.Sample], None]:
        msgtype = POSE_TYPES[self.streams[vehicle_id].pose_type]

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                pose = m.pose_of(m.deserialize(sample.payload.to_bytes(), msgtype))
            except m.SensorInputError as exc:
                self.log(f"camera driver: drone {vehicle_id}: {exc}")
                return
            with self._lock:
                self._poses[vehicle_id] = pose

        return on_sample

    def _publish(self, vehicle_id: int, publisher: StreamPublisher) -> None:
        with self._lock:
            pose = self._poses.get(vehicle_id)
            others = [p.position for k, p in self._poses.items() if k != vehicle_id]
        if pose is None:
            return
        started = time.perf_counter()
        camera = self.cameras[vehicle_id]
        T = camera_to_world(pose, self.mount)
        depth = render_with_peers(camera.render(T), self._rays, T, others, self.drone_radius_m, self.camera_settings)
        self.render_s += time.perf_counter() - started
        stream = self.streams[vehicle_id]
        publisher.put(stream.info_topic, m.camera_info_message(pose.t, self.intrinsics))
        publisher.put(stream.depth_topic, m.image_message(pose.t, depth))
        self.published[vehicle_id] += 1
        if self.on_frame is not None:
            self.on_frame(vehicle_id, pose.t, T, depth)


class OdometryPublisher:
    """Each vehicle's true pose as `nav_msgs/msg/Odometry` on /drone<k>/<pose topic>, from the simulator's loop,
    through a Zenoh router session of its own (the robot side's rmw_zenohd: the camera driver and the agents
    connect to it)."""

    def __init__(self, listen: list[str], stream: SensorStreamSettings, vehicle_ids: list[int]) -> None:
        config = session_config(stream.model_copy(update={"mode": "router", "connect": [], "listen": listen}))
        self.session = zenoh.open(config)
        self.streams = {k: stream.under_vehicle(k) for k in vehicle_ids}
        self.publishers = {k: StreamPublisher(self.session, s, gid=k) for k, s in self.streams.items()}
        self.published = 0

    def publish(self, vehicle_id: int, body: Body) -> None:
        roll, pitch = tilt(body)
        pose = body_pose(time.time(), body.position, roll, pitch, body.yaw)
        self.publishers[vehicle_id].put(self.streams[vehicle_id].pose_topic, m.odometry_message(pose))
        self.published += 1

    def close(self) -> None:
        self.session.close()


def cameras_command(config: SwarmConfig, on_frame: FrameHook | None = None) -> int:
    """`swarm cameras`: the simulated depth camera of each of config.mission.drones vehicles, as a camera driver
    on ROS 2 over Zenoh (camera.stream), until SIGINT/SIGTERM. It needs each vehicle's odometry: the simulator's
    (sim.sensor_listen) or any publisher's. `on_frame` is handed every frame published (vehicle id, stamp,
    camera-to-world transform, depth in metres), e.g. to record it."""
    world = load_world(config.mission.world)
    ids = list(range(1, config.mission.drones + 1))
    driver = CameraDriver(
        world,
        config.camera,
        ids,
        config.mission.seed,
        log=lambda text: print(text, file=sys.stderr, flush=True),
        drone_radius_m=config.sim.drone_radius_m,
        on_frame=on_frame,
    )
    stop = threading.Event()
    handlers = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    print(
        f"swarm cameras: {len(ids)} depth cameras at {config.camera.rate_hz:g} Hz on "
        f"{', '.join(config.camera.stream.connect) or 'no endpoint'} ({config.camera.stream.layout} keys, "
        f"{config.camera.stream.under_vehicle(1).depth_topic} ...)",
        flush=True,
    )
    try:
        driver.run(stop)
    except Exception as exc:
        raise SwarmError(f"camera driver: {zenoh_error_text(exc)}") from None
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    frames = sum(driver.published.values())
    print(
        f"swarm cameras: published {frames} images, render {1000 * driver.render_s / max(frames, 1):.1f} ms each",
        flush=True,
    )
    return 0
