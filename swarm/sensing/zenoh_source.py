"""A camera on ROS 2, heard through Zenoh: depth, camera info and pose subscriptions in a session of its own.

The session is apart from the swarm's (its own endpoints, no swarm TLS or ACL, no swarm keys): it faces the
robot's ROS 2 side, `rmw_zenohd` and the camera driver with rmw_zenoh, or a zenoh-bridge-ros2dds. Key layouts
(`camera.stream.layout`):
- rmw_zenoh: `<domain>/<topic without its leading slash>/<DDS type>/<type hash>`, the hash (RIHS01, different in
  every ROS distribution) matched with `*`; e.g. `0/camera/depth/image_rect_raw/sensor_msgs::msg::dds_::Image_/*`.
- bridge: `[<namespace>/]<topic without its leading slash>`.
Payloads are CDR with the encapsulation header, decoded by `FrameAssembler` (in Zenoh's callback thread, under a
lock); `wait_frame` hands the newest frame to the mapping thread and counts the ones it never took.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from swarm.bus.session import zenoh_error_text
from swarm.config import SensorStreamSettings
from swarm.errors import BusError
from swarm.sensing.bags import BagRecorder
from swarm.sensing.frames import DepthFrame
from swarm.sensing.messages import CAMERA_INFO, IMAGE, ODOMETRY, POSE_STAMPED
from swarm.sensing.poses import PoseBuffer
from swarm.sensing.stream import FrameAssembler

POSE_TYPES = {"odometry": ODOMETRY, "pose_stamped": POSE_STAMPED}


def dds_type_name(msgtype: str) -> str:
    """`sensor_msgs/msg/Image` -> `sensor_msgs::msg::dds_::Image_` (rmw_zenoh's mangled type in the key)."""
    package, kind, name = msgtype.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def topic_key(settings: SensorStreamSettings, topic: str, msgtype: str) -> str:
    """The key expression a ROS 2 topic of `msgtype` is published under, in the configured layout."""
    name = topic.lstrip("/")
    if settings.layout == "rmw_zenoh":
        return f"{settings.domain_id}/{name}/{dds_type_name(msgtype)}/*"
    return f"{settings.namespace}/{name}" if settings.namespace else name


def session_config(settings: SensorStreamSettings) -> zenoh.Config:
    config = zenoh.Config()
    values: dict[str, Any] = {"mode": settings.mode, "connect/endpoints": settings.connect,
                              "listen/endpoints": settings.listen, "scouting/multicast/enabled": False}
    for key, value in values.items():
        try:
            config.insert_json5(key, json.dumps(value))
        except Exception as exc:
            raise BusError(f"invalid sensor stream setting {key}={value}: {zenoh_error_text(exc)}") from None
    return config


class ZenohSensorSource:
    def __init__(self, settings: SensorStreamSettings, mount: np.ndarray, record: Path | None = None) -> None:
        self.settings = settings
        self.record = record  # a ROS 2 bag of every message received, as received
        self.recorder: BagRecorder | None = None
        self.frames = FrameAssembler(mount, PoseBuffer(max_gap_s=settings.max_gap_s, max_hold_s=settings.max_hold_s))
        self._lock = threading.Lock()
        self._new = threading.Condition(self._lock)
        self._latest: DepthFrame | None = None
        self.not_taken = 0  # frames replaced by a newer one before the mapping thread took them
        self._session: zenoh.Session | None = None
        self._subscribers: list[Any] = []

    def start(self) -> None:
        """Open the session and subscribe; BusError (one line) when the session cannot open."""
        try:
            self._session = zenoh.open(session_config(self.settings))
        except Exception as exc:
            raise BusError(f"sensor stream session: {zenoh_error_text(exc)}") from None
        if self.record is not None:
            self.recorder = BagRecorder(self.record)
        s = self.settings
        pose_type = POSE_TYPES[s.pose_type]
        topics: list[tuple[str, str, Callable[[bytes], None]]] = [
            (s.info_topic, CAMERA_INFO, self.frames.on_camera_info),
            (s.pose_topic, pose_type, lambda raw: self.frames.on_pose(raw, pose_type)),
            (s.depth_topic, IMAGE, self.frames.on_image),
        ]
        for topic, msgtype, handler in topics:
            key = topic_key(s, topic, msgtype)
            self._subscribers.append(self._session.declare_subscriber(key, self._on_sample(handler, topic, msgtype)))

    def _on_sample(self, handler: Callable[[bytes], None], topic: str,
                   msgtype: str) -> Callable[[zenoh.Sample], None]:
        def deliver(sample: zenoh.Sample) -> None:
            raw = sample.payload.to_bytes()
            if self.recorder is not None:
                self.recorder.write(topic, msgtype, time.time_ns(), raw)
            with self._new:
                handler(raw)
                ready = self.frames.take()
                if ready:
                    self.not_taken += len(ready) - 1 + (self._latest is not None)
                    self._latest = ready[-1]
                    self._new.notify_all()

        return deliver

    def wait_frame(self, timeout_s: float) -> DepthFrame | None:
        """The newest frame not taken yet, waiting up to `timeout_s` for one; None when none came."""
        with self._new:
            if self._latest is None:
                self._new.wait_for(lambda: self._latest is not None, timeout_s)
            frame, self._latest = self._latest, None
            return frame

    def counters(self) -> dict[str, int]:
        with self._lock:
            return {"frames": self.frames.frames, "not_taken": self.not_taken, **dict(self.frames.dropped)}

    def close(self) -> None:
        for subscriber in self._subscribers:
            subscriber.undeclare()
        self._subscribers.clear()
        if self._session is not None:
            self._session.close()
            self._session = None
        if self.recorder is not None:
            self.recorder.close()
