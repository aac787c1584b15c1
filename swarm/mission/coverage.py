"""The swarm's map as the observer builds it, and how much of the world it covers.

Patches are read from the directory the agents write them to, decoded with the same validating decoder an agent
uses on received patches (a bad file is counted and skipped, never fused), and fused into one map. Its
`explored_fraction` is measured against the world's reachable free space (`swarm.sim.coverage`).

Each producer's patches are also fused into a map of their own, so the report can tell what each drone's camera
contributed (`explored_by_agent`) and how much of the explored space more than one drone saw
(`overlap_fraction`: the redundancy coordination is meant to keep low).

`unexplored` lists the largest 26-connected pieces of the reachable space still unknown, with their bounding
boxes: where the swarm did not go (a room behind a door its planner found too narrow, a storey never entered),
which is what a mission that ends below its coverage target has to show.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage

from swarm.config import SwarmConfig
from swarm.patches.fused import UNKNOWN, FusedMap
from swarm.patches.lattice import Lattice
from swarm.patches.patch import Patch
from swarm.patches.wire import PatchDecodeError, decode_patch
from swarm.sim.coverage import ReachableSpace, mission_reachable_space
from swarm.sim.worlds import load_world, mission_volume

UNEXPLORED_REGIONS_KEPT = 3
MIN_UNEXPLORED_M3 = 0.1  # smaller unknown pieces (corners, specks) are not regions


def unexplored_regions(
    space: ReachableSpace, known: np.ndarray, keep: int = UNEXPLORED_REGIONS_KEPT
) -> list[dict[str, Any]]:
    """The `keep` largest 26-connected pieces of `space` whose cells are not `known` ((N,) bool, in the order of
    `space.centres`), largest first: volume and bounding box."""
    unknown = np.zeros(space.mask.size, dtype=bool)
    unknown[np.flatnonzero(space.mask.ravel())] = ~np.asarray(known, dtype=bool)
    labels, count = ndimage.label(unknown.reshape(space.mask.shape), structure=np.ones((3, 3, 3), dtype=bool))
    if count == 0:
        return []
    sizes = np.bincount(labels.ravel())[1:]
    boxes = ndimage.find_objects(labels)
    cell_m3 = space.resolution**3
    regions = []
    for index in np.argsort(-sizes, kind="stable")[:keep]:
        if sizes[index] * cell_m3 < MIN_UNEXPLORED_M3:
            break
        box = boxes[index]
        assert box is not None  # every label from 1 to count has cells
        lo = space.origin + np.array([sl.start for sl in box]) * space.resolution
        hi = space.origin + np.array([sl.stop for sl in box]) * space.resolution
        regions.append(
            {
                "volume_m3": round(float(sizes[index] * cell_m3), 2),
                "lo": [round(float(v), 2) for v in lo],
                "hi": [round(float(v), 2) for v in hi],
            }
        )
    return regions


def overlap_fraction(known: np.ndarray) -> float:
    """Share of the cells known by at least one producer that two or more producers know.

    `known` is (producers, cells) bool. A cell one drone saw and another drone saw again is redundant work,
    whoever saw it first; 0.0 when no cell is known (nothing explored, so nothing overlaps).
    """
    known = np.asarray(known, dtype=bool)
    if known.ndim != 2 or known.shape[0] == 0:
        return 0.0
    counts = np.count_nonzero(known, axis=0)
    seen = int(np.count_nonzero(counts >= 1))
    return int(np.count_nonzero(counts >= 2)) / seen if seen else 0.0


class SwarmCoverage:
    def __init__(self, config: SwarmConfig, patches_dir: Path) -> None:
        self.config = config
        self.patches_dir = patches_dir
        world = load_world(config.mission.world)
        self.world = world
        self.space = mission_reachable_space(world, config)
        lo, hi = mission_volume(world, config.mission.volume)
        self.bounds = (lo, hi)
        self.lattice = Lattice.from_settings(config.mapping)
        self.fused = FusedMap(self.lattice, (lo, hi), config.mapping.known_weight)
        self.seen: set[str] = set()
        self.rejected: dict[str, int] = {}
        self.timeline: list[tuple[float, float]] = []
        self.fraction = 0.0
        self.by_producer: dict[int, FusedMap] = {}
        self.producer_timeline: dict[int, list[tuple[float, float]]] = {}
        self.overlap = 0.0
        self.unexplored: list[dict[str, Any]] = []
        self.patch_bytes = 0  # the wire bytes of the patches fused
        self.map_bytes = 0  # the fused map's wire size at the last final update
        self._producer_known: dict[int, np.ndarray] = {}  # reachable cells each producer's map knows (cached)
        self._changed: set[int] = set()  # producers whose map grew since their mask was computed
        self._cells = self.fused.addresses(self.space.centres)  # every map here has the same lattice and bounds
        self._lock = threading.Lock()

    def update(self, t: float, final: bool = False) -> None:
        """Fuse the patch files not seen yet, then measure explored_fraction, per producer and overlap; `final`:
        the map's wire size too (a pass over the whole map, 0.25 s for the office: only at the end)."""
        with self._lock:
            for path in sorted(self.patches_dir.glob("*.patch")):
                if path.name in self.seen:
                    continue
                self.seen.add(path.name)
                try:
                    data = path.read_bytes()
                    patch = decode_patch(data, self.lattice, self.config.mapping.max_patch_bytes)
                except PatchDecodeError as exc:
                    self.rejected[exc.reason] = self.rejected.get(exc.reason, 0) + 1
                    continue
                except OSError:
                    self.seen.discard(path.name)  # being written: try again next time
                    continue
                if self.fused.add(patch):
                    self.patch_bytes += len(data)
                self._add_to_producer(patch)
            known = self.fused.state_at(self._cells) != UNKNOWN
            self.fraction = float(np.count_nonzero(known)) / len(known) if len(known) else 0.0
            self.unexplored = unexplored_regions(self.space, known)
            self.timeline.append((round(t, 2), round(self.fraction, 4)))
            self._measure_producers(t)
            if final:
                self.map_bytes = self.fused.wire_size()

    def _add_to_producer(self, patch: Patch) -> None:
        """Fuse a patch into its producer's own map: what that drone's camera saw, whoever relayed it."""
        producer = patch.id.producer
        own = self.by_producer.get(producer)
        if own is None:
            own = FusedMap(self.lattice, self.bounds, self.config.mapping.known_weight)
            self.by_producer[producer] = own
        if own.add(patch):
            self._changed.add(producer)

    def _measure_producers(self, t: float) -> None:
        """Per-producer explored fractions and the overlap; only maps that grew are queried again (the query
        over every reachable cell is the cost, and most producers add nothing between two updates)."""
        for producer in self._changed:
            self._producer_known[producer] = self.by_producer[producer].state_at(self._cells) != UNKNOWN
        self._changed.clear()
        cells = len(self.space.centres)
        for producer, known in sorted(self._producer_known.items()):
            share = float(np.count_nonzero(known)) / cells if cells else 0.0
            self.producer_timeline.setdefault(producer, []).append((round(t, 2), round(share, 4)))
        masks = list(self._producer_known.values())
        self.overlap = overlap_fraction(np.stack(masks)) if masks else 0.0

    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """The fused map's surface now: (V,3) vertices, (F,3) triangles (both empty before the first patch)."""
        with self._lock:
            if self.fused.voxel_count == 0:
                return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int32)
            return self.fused.mesh()

    def by_producer_now(self) -> dict[int, float]:
        """Each producer's latest explored share (`explored_by_agent`'s last samples)."""
        with self._lock:
            return {k: v[-1][1] for k, v in self.producer_timeline.items() if v}

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
            "explored_by_agent": {str(k): list(v) for k, v in sorted(self.producer_timeline.items())},
            "overlap_fraction": round(self.overlap, 4),
            "unexplored": self.unexplored,
            "patch_bytes": self.patch_bytes,
            "map_bytes": self.map_bytes,
        }
