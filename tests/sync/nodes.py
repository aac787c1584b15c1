"""Swarms of `swarm mapnode` processes for sync tests: real Zenoh sessions, real mapping, separate processes.

Small and fast on purpose: the box world, 0.2 m voxels, 3-frame patches from a 64x48 camera, small chunks so
every patch still travels in several of them.
"""

from __future__ import annotations

from pathlib import Path

from swarm.mission.mapnodes import NodeSpec, holds_all
from swarm.mission.mapnodes import NodeSwarm as _NodeSwarm

__all__ = ["FAST", "NodeSpec", "NodeSwarm", "holds_all"]

FAST = [
    "mission.world=box",
    "mapping.voxel_size_m=0.2",
    "mapping.patch_frames=3",
    "camera.width=64",
    "camera.height=48",
    "sync.chunk_bytes=2048",
    "sync.period_s=0.1",
    "sync.grace_s=0.5",
    "agent.heartbeat_hz=5",
]


class NodeSwarm(_NodeSwarm):
    def __init__(self, tmp: Path, mission: str = "synctest", mode: str = "peer") -> None:
        super().__init__(tmp, mission, mode, FAST)
