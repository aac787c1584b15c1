"""A camera on ROS 2, heard through rclpy (camera.source = "ros2"; any RMW, Fast DDS by default).

rclpy comes from the ROS 2 wheels on PyPI, an optional extra: `pip install 'swarm[ros2]'`. The node subscribes
with `raw=True`, so rclpy hands over the serialised CDR and the messages take exactly the path of the Zenoh source
(`StreamInbox`, `FrameAssembler`); rclpy's executor spins in a thread of its own, in a context of its own, with
the sensor-data QoS (best effort: it matches a reliable publisher and a best-effort one).
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np

from swarm.config import SensorStreamSettings
from swarm.errors import SwarmError
from swarm.sensing.stream import StreamInbox

ROS2_EXTRA = "camera.source = \"ros2\" needs rclpy: pip install 'swarm[ros2]' (the ROS 2 wheels from PyPI)"


def _ros_type(msgtype: str) -> Any:
    """The rclpy message class of `sensor_msgs/msg/Image` and the like."""
    import importlib

    package, _, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), name)


class Ros2SensorSource(StreamInbox):
    def __init__(
        self,
        settings: SensorStreamSettings,
        mount: np.ndarray,
        record: Path | None = None,
        node_name: str = "swarm_camera",
    ) -> None:
        super().__init__(settings, mount, record)
        self.node_name = node_name
        self._context: Any = None
        self._node: Any = None
        self._executor: Any = None
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        try:
            import rclpy
            from rclpy.executors import SingleThreadedExecutor
            from rclpy.qos import qos_profile_sensor_data
        except ImportError as exc:
            raise SwarmError(f"{ROS2_EXTRA} ({exc})") from None
        self._context = rclpy.Context()
        rclpy.init(context=self._context)
        self._node = rclpy.create_node(self.node_name, context=self._context)
        self.open_recording()
        for topic, msgtype, handler in self.topics():

            def on_raw(raw: bytes, topic: str = topic, msgtype: str = msgtype, handler: Any = handler) -> None:
                self.deliver(topic, msgtype, handler, bytes(raw))

            self._node.create_subscription(_ros_type(msgtype), topic, on_raw, qos_profile_sensor_data, raw=True)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self._node)
        self._thread = threading.Thread(target=self._spin, name="rclpy", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            self._executor.spin()
        except Exception:  # the context was shut down under it (close): the executor's way of stopping
            pass

    def close(self) -> None:
        if self._context is not None:
            self._executor.shutdown()
            self._node.destroy_node()
            self._context.try_shutdown()
            if self._thread is not None:
                self._thread.join(timeout=5.0)
            self._context = None
        self.close_recording()
