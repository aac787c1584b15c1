"""A camera on ROS 2, heard through Zenoh: depth, camera info and pose subscriptions in a session of its own.

The session is apart from the swarm's (its own endpoints, no swarm TLS or ACL, no swarm keys): it faces the
robot's ROS 2 side, `rmw_zenohd` and the camera driver with rmw_zenoh, or a zenoh-bridge-ros2dds. Key layouts
(`camera.stream.layout`):
- rmw_zenoh: `<domain>/<topic without its leading slash>/<DDS type>/<type hash>`, the hash (RIHS01, different in
  every ROS distribution) matched with `*`; e.g. `0/camera/depth/image_rect_raw/sensor_msgs::msg::dds_::Image_/*`.
- bridge: `[<namespace>/]<topic without its leading slash>`.
Payloads are CDR with the encapsulation header, decoded by `FrameAssembler` (in Zenoh's callback thread, under a
lock; `StreamInbox`); `wait_frame` hands the newest frame to the mapping thread.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from swarm.bus.session import zenoh_error_text
from swarm.config import SensorStreamSettings
from swarm.errors import BusError
from swarm.sensing.stream import StreamInbox


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
    values: dict[str, Any] = {
        "mode": settings.mode,
        "connect/endpoints": settings.connect,
        "listen/endpoints": settings.listen,
        "connect/timeout_ms": round(settings.connect_timeout_s * 1000),  # open waits for an endpoint this long
        "scouting/multicast/enabled": False,
    }
    for key, value in values.items():
        try:
            config.insert_json5(key, json.dumps(value))
        except Exception as exc:
            raise BusError(f"invalid sensor stream setting {key}={value}: {zenoh_error_text(exc)}") from None
    return config


class ZenohSensorSource(StreamInbox):
    def __init__(self, settings: SensorStreamSettings, mount: np.ndarray, record: Path | None = None) -> None:
        super().__init__(settings, mount, record)
        self._session: zenoh.Session | None = None
        self._subscribers: list[Any] = []

    def start(self) -> None:
        """Open the session and subscribe; BusError (one line) when the session cannot open."""
        try:
            self._session = zenoh.open(session_config(self.settings))
        except Exception as exc:
            raise BusError(f"sensor stream session: {zenoh_error_text(exc)}") from None
        self.open_recording()
        for topic, msgtype, handler in self.topics():
            key = topic_key(self.settings, topic, msgtype)
            self._subscribers.append(self._session.declare_subscriber(key, self._on_sample(handler, topic, msgtype)))

    def _on_sample(self, handler: Callable[[bytes], None], topic: str, msgtype: str) -> Callable[[zenoh.Sample], None]:
        def on_sample(sample: zenoh.Sample) -> None:
            self.deliver(topic, msgtype, handler, sample.payload.to_bytes())

        return on_sample

    def close(self) -> None:
        for subscriber in self._subscribers:
            subscriber.undeclare()
        self._subscribers.clear()
        if self._session is not None:
            self._session.close()
            self._session = None
        self.close_recording()
