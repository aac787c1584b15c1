"""A camera on ROS 2 heard through real Zenoh sessions on loopback: a publisher stands in for the camera driver
and the autopilot bridge (rmw_zenoh key layout with a type hash and its attachment, or the ros2dds bridge's),
and the source gives frames with the pose at each image's stamp; junk on the same keys is counted, not mapped."""

from __future__ import annotations

import json
import random
import struct
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
import zenoh
from scipy.spatial.transform import Rotation

from swarm.config import SensorStreamSettings
from swarm.errors import BusError
from swarm.mission.ports import find_free_base
from swarm.sensing import messages as m
from swarm.sensing.frames import mount_transform
from swarm.sensing.zenoh_source import ZenohSensorSource, topic_key
from tests.helpers import loopback_zenoh, worker_ports

K = np.array([[8.0, 0.0, 7.5], [0.0, 8.0, 5.5], [0.0, 0.0, 1.0]])


def test_keys_follow_rmw_zenoh_and_the_bridge() -> None:
    rmw = SensorStreamSettings(domain_id=3)
    assert topic_key(rmw, "/camera/depth/image_rect_raw", m.IMAGE) == (
        "3/camera/depth/image_rect_raw/sensor_msgs::msg::dds_::Image_/*"
    )
    bridge = SensorStreamSettings(layout="bridge", namespace="bot1")
    assert topic_key(bridge, "/odom", m.ODOMETRY) == "bot1/odom"
    assert topic_key(SensorStreamSettings(layout="bridge"), "/odom", m.ODOMETRY) == "odom"


@pytest.fixture
def camera_side() -> Iterator[tuple[zenoh.Session, str]]:
    with loopback_zenoh("peer") as side:
        yield side


def _attachment(seq: int) -> bytes:
    """rmw_zenoh's: int64 sequence number, int64 source timestamp (ns), GID length (16), GID."""
    return struct.pack("<qqB", seq, 0, 16) + bytes(16)


@pytest.mark.parametrize("layout", ["rmw_zenoh", "bridge"])
@pytest.mark.bus
def test_frames_arrive_with_the_pose_at_their_stamp_and_junk_is_counted(
    camera_side: tuple[zenoh.Session, str], layout: str
) -> None:
    publisher, endpoint = camera_side
    settings = SensorStreamSettings(layout=layout, namespace="bot1" if layout == "bridge" else "", connect=[endpoint])
    source = ZenohSensorSource(settings, mount_transform((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)))
    source.start()
    try:

        def key(topic: str, msgtype: str) -> str:
            base = topic_key(settings, topic, msgtype)
            return base.replace("*", "RIHS01_" + "ab" * 32)  # the distribution's type hash

        def put(topic: str, msgtype: str, payload: bytes, seq: int) -> None:
            publisher.put(key(topic, msgtype), payload, attachment=_attachment(seq))

        depth = np.full((12, 16), 3.0, dtype=np.float32)
        yaw = Rotation.from_euler("z", 90, degrees=True).as_quat()
        # subscriptions take a moment to reach the publisher: send camera info until the source has it
        for seq in range(200):
            put(
                settings.info_topic,
                m.CAMERA_INFO,
                m.serialize(m.camera_info_message(0.0, m.Intrinsics(16, 12, K))),
                seq,
            )
            if source.wait_frame(0.01) is None and source.frames.intrinsics is not None:
                break
        assert source.frames.intrinsics is not None
        put(settings.pose_topic, m.ODOMETRY, m.serialize(m.odometry_message(m.Pose(10.0, np.zeros(3), yaw))), 1)
        put(settings.depth_topic, m.IMAGE, b"\x00\x01\x00\x00 not an image", 2)
        put(settings.depth_topic, m.IMAGE, m.serialize(m.image_message(10.1, depth)), 3)
        put(
            settings.pose_topic,
            m.ODOMETRY,
            m.serialize(m.odometry_message(m.Pose(10.2, np.array([2.0, 0.0, 0.0]), yaw))),
            4,
        )
        frame = source.wait_frame(10.0)
        assert frame is not None and frame.t == pytest.approx(10.1)
        assert np.allclose(frame.T_world_cam[:3, 3], [1.0, 0.0, 0.0])  # half way between the poses
        assert np.allclose(frame.T_world_cam[:3, 2], [0.0, 1.0, 0.0])  # looking north
        assert source.counters()["bad image"] == 1 and source.counters()["frames"] == 1
    finally:
        source.close()


@pytest.mark.bus
def test_the_sensor_session_waits_for_a_router_that_comes_up_late_and_gives_up_on_one_that_never_does() -> None:
    lo, hi = worker_ports()
    port = find_free_base("127.0.0.1", 1, "tcp", random.randrange(lo, hi - 100), stop=hi)
    endpoint = f"tcp/127.0.0.1:{port}"
    mount = mount_transform((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    never = ZenohSensorSource(SensorStreamSettings(connect=[endpoint], connect_timeout_s=1.0), mount)
    started = time.monotonic()
    with pytest.raises(BusError, match="sensor stream session"):
        never.start()
    assert 0.9 < time.monotonic() - started < 8.0  # it tried for its second, then said so
    late = ZenohSensorSource(SensorStreamSettings(connect=[endpoint], connect_timeout_s=20.0), mount)
    router: list[zenoh.Session] = []

    def router_comes_up() -> None:
        config = zenoh.Config()
        config.insert_json5("mode", '"router"')
        config.insert_json5("listen/endpoints", json.dumps([endpoint]))
        config.insert_json5("scouting/multicast/enabled", "false")
        router.append(zenoh.open(config))

    timer = threading.Timer(1.5, router_comes_up)
    timer.start()
    try:
        late.start()  # blocks until the router listens
        assert router, "the session opened before any router listened"
    finally:
        timer.join()
        late.close()
        for session in router:
            session.close()
