"""Phantom obstacles: surface in the swarm's map where a drone flew and the building has none.

The cameras see the other drones; an agent that failed to mask one (`camera.peer_mask_m`) maps it, and the map
then holds an obstacle along that drone's path which the building does not have. The referee checks the final
map against the truth: a vertex of `map.ply` within `NEAR_M` of a flown path (the drone body's centre, from the
observer's trajectories, filled in every `PATH_STEP_M`) that is also more than `NEAR_M` from the world's surface
is a phantom. Surface near a path but also near the world (a wall passed close by, the floor at take-off) is not.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from swarm.sim.worlds import World

NEAR_M = 0.3
PATH_STEP_M = 0.05
WORST_LISTED = 5


def flown_paths(trajectories: Mapping[str, Sequence[Sequence[float]]], lift_m: float) -> np.ndarray:
    """(N, 3) points along every drone's trajectory ([t, x, y, z] samples), `lift_m` above each position."""
    points = [np.empty((0, 3))]
    for samples in trajectories.values():
        xyz = np.asarray(samples, dtype=float).reshape(-1, 4)[:, 1:] + np.array([0.0, 0.0, lift_m])
        points.append(xyz[-1:])
        for a, b in zip(xyz[:-1], xyz[1:]):
            n = max(int(np.linalg.norm(b - a) / PATH_STEP_M), 1)
            points.append(a + np.linspace(0.0, 1.0, n, endpoint=False)[:, None] * (b - a))
    return np.concatenate(points)


def phantom_check(
    mesh: Path, trajectories: Mapping[str, Sequence[Sequence[float]]], world: World, lift_m: float
) -> dict[str, Any] | None:
    """Vertices of `mesh` near the flown paths, and the phantoms among them; None without a map or paths."""
    if not mesh.exists():
        return None
    vertices = np.asarray(o3d.io.read_triangle_mesh(mesh).vertices)
    paths = flown_paths(trajectories, lift_m)
    if len(vertices) == 0 or len(paths) == 0:
        return None
    distance, _ = cKDTree(paths).query(vertices, distance_upper_bound=NEAR_M)
    near = np.asarray(distance) < NEAR_M
    off_world = np.zeros(len(vertices), dtype=bool)
    if near.any():
        off_world[near] = world.distance(vertices[near]) > NEAR_M
    worst = vertices[off_world][:WORST_LISTED]
    return {
        "vertices": int(len(vertices)),
        "near_paths": int(near.sum()),
        "phantoms": int(off_world.sum()),
        "examples": [[round(float(c), 2) for c in v] for v in worst],
    }
