"""The swarm's map as the observer builds it, and how much of the world it covers.

Patches are read from the directory the agents write them to, decoded with the same validating decoder an agent
uses on received patches (a bad file is counted and skipped, never fused), and fused into one map. Its
`explored_fraction` is measured against the world's reachable free space (`swarm.sim.coverage`).
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

from swarm.config import SwarmConfig
from swarm.patches.fused import UNKNOWN, FusedMap
from swarm.patches.lattice import Lattice
from swarm.patches.wire import PatchDecodeError, decode_patch
from swarm.sim.coverage import explored_fraction, mission_reachable_space
from swarm.sim.worlds import load_world, mission_volume


class SwarmCoverage:
    def __init__(self, config: SwarmConfig, patches_dir: Path) -> None:
        self.config = config
        self.patches_dir = patches_dir
        world = load_world(config.mission.world)
        self.space = mission_reachable_space(world, config)
        lo, hi = mission_volume(world, config.mission.volume)
        self.lattice = Lattice.from_settings(config.mapping)
        self.fused = FusedMap(self.lattice, (lo, hi), config.mapping.known_weight)
        self.seen: set[str] = set()
        self.rejected: dict[str, int] = {}
        self.timeline: list[tuple[float, float]] = []
        self.fraction = 0.0
        self._lock = threading.Lock()

    def update(self, t: float) -> None:
        """Fuse the patch files not seen yet, then measure explored_fraction."""
        with self._lock:
            for path in sorted(self.patches_dir.glob("*.patch")):
                if path.name in self.seen:
                    continue
                self.seen.add(path.name)
                try:
                    patch = decode_patch(path.read_bytes(), self.lattice, self.config.mapping.max_patch_bytes)
                except PatchDecodeError as exc:
                    self.rejected[exc.reason] = self.rejected.get(exc.reason, 0) + 1
                    continue
                except OSError:
                    self.seen.discard(path.name)  # being written: try again next time
                    continue
                self.fused.add(patch)
            self.fraction = explored_fraction(self.space, lambda points: self.fused.state_at(points) != UNKNOWN)
            self.timeline.append((round(t, 2), round(self.fraction, 4)))

    def write_mesh(self, path: Path) -> None:
        with self._lock:
            if self.fused.voxel_count > 0:
                self.fused.write_mesh(path)

    def snapshot(self) -> dict[str, Any]:
        return {
            "explored_fraction": round(self.fraction, 4),
            "explored_timeline": self.timeline,
            "patches_fused": len(self.seen) - sum(self.rejected.values()),
            "patches_rejected": self.rejected,
            "reachable_cells": int(self.space.mask.sum()),
        }
