"""The agent's depth sensor interface: one `capture` call per frame, so a real camera can replace the simulated one.

The agent calls `DepthSource.capture` from a worker thread at camera.rate_hz with the drone's latest telemetry
pose; the call blocks until a frame is ready. A real camera driver implements `capture` by grabbing its latest
frame and attaching the pose (plus its fixed mounting transform), with depth converted to the conventions of
`swarm.sim.camera`: float32 z-depth in metres, 0 = invalid, pixel (u, v) centred at (u + 0.5, v + 0.5).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from swarm.config import CameraSettings, SwarmConfig, Vec3
from swarm.sensing.frames import DepthFrame
from swarm.sim.camera import DepthCamera
from swarm.sim.worlds import World, load_world

__all__ = ["DepthFrame", "DepthSource", "SimulatedDepthSource", "StreamSource", "make_depth_source"]


class DepthSource(Protocol):
    def capture(self, index: int, t: float, position: Vec3, yaw_enu_deg: float) -> DepthFrame:
        """A depth frame taken at the given drone pose (world frame, ENU yaw in degrees); blocking."""
        ...


class StreamSource(Protocol):
    """A camera that publishes (`swarm.sensing.zenoh_source.ZenohSensorSource`): frames come with their own
    poses, when the camera sends them."""

    def start(self) -> None: ...

    def wait_frame(self, timeout_s: float) -> DepthFrame | None: ...

    def counters(self) -> dict[str, int]: ...

    def close(self) -> None: ...


class SimulatedDepthSource:
    """Renders the world mesh with a `DepthCamera` at the pose it is given."""

    def __init__(self, world: World, settings: CameraSettings, seed: int = 0) -> None:
        self.camera = DepthCamera(world, settings, seed)

    def capture(self, index: int, t: float, position: Vec3, yaw_enu_deg: float) -> DepthFrame:
        T = self.camera.pose(position, yaw_enu_deg)
        return DepthFrame(index, t, self.camera.render(T), self.camera.intrinsics.copy(), T)


def make_depth_source(config: SwarmConfig, world: World | None = None) -> DepthSource:
    """The agent's depth source: for now always the simulated camera in config.mission.world (pass the world if
    it is already loaded).

    Each drone's noise stream is seeded from (mission.seed, agent.id), so runs repeat and drones differ.
    """
    seed = int(np.random.SeedSequence([config.mission.seed % 2**32, config.agent.id]).generate_state(1)[0])
    return SimulatedDepthSource(world or load_world(config.mission.world), config.camera, seed)
