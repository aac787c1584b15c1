"""The agent's depth sensor interface: a camera that publishes, its frames coming with their own poses.

Every source the agent maps from (`camera.source`) is one of these: the simulator's cameras and a real camera on
ROS 2 heard through Zenoh (`swarm.sensing.zenoh_source`), the same topics through rclpy
(`swarm.sensing.ros2_source`), or a recorded bag (`swarm.sensing.replay_source`). The agent never renders a world
itself: it learns the building only from these frames (docs/architecture.md, "The agent's inputs"). Depth follows
ROS conventions as `swarm.sensing.frames.DepthFrame` holds them: float32 z-depth in metres, 0 = invalid, pixel
(u, v) centred at (u + 0.5, v + 0.5), pose camera-to-world in the optical frame.
"""

from __future__ import annotations

from typing import Protocol

from swarm.sensing.frames import DepthFrame

__all__ = ["DepthFrame", "StreamSource"]


class StreamSource(Protocol):
    """Frames when the camera sends them, each with the pose it was taken at."""

    def start(self) -> None: ...

    def wait_frame(self, timeout_s: float) -> DepthFrame | None: ...

    def counters(self) -> dict[str, int]: ...

    def close(self) -> None: ...
