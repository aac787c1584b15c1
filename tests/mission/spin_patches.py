"""Real sealed patches for the observer's tests: one drone turning on the spot at the box world's start."""

from __future__ import annotations

from collections.abc import Iterable

from swarm.config import SwarmConfig
from swarm.patches.mapper import Mapper
from swarm.sim.camera import DepthCamera
from swarm.sim.worlds import load_world


def spin_patches(
    config: SwarmConfig, producer: int = 1, epoch: int = 1, yaws: Iterable[int] = range(0, 360, 30)
) -> list[bytes]:
    """The wire bytes of every patch `producer` seals looking around at 1.2 m, one frame per yaw (degrees)."""
    world = load_world("box")
    camera = DepthCamera(world, config.camera)
    mapper = Mapper(config.mapping, producer=producer, epoch=epoch, bounds=world.bounds)
    start = world.default_start
    for i, yaw in enumerate(yaws):
        frame = camera.frame(i, float(i), (start[0], start[1], 1.2), float(yaw))
        mapper.integrate(frame.depth, frame.K, frame.T_world_cam, frame.t, config.camera.max_range_m)
    mapper.seal()
    return [mapper.data(pid) for pid in mapper.held_ids()]
