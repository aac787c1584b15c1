"""Ground truth for the `explored_fraction` metric: how much of the space a drone could reach the map knows.

Definition (computed by the mission observer against the world mesh, never by the agents):

1. Grid. The mission volume [lo, hi) (mission.volume, else the world mesh bounds) is cut into cubic cells of
   edge `resolution`, by default mapping.planning_resolution_m (0.2 m); cell (i, j, k) is
   lo + [i, i+1) x [j, j+1) x [k, k+1) * resolution, and a partial last cell on an axis is kept.
2. Free. A cell is free when its centre is outside every solid of the world and at least `clearance` from the
   mesh surface, by default the drone radius sim.drone_radius_m (0.2 m): its centre is a position the drone's
   collision sphere can occupy.
3. Reachable. The reachable space is the 6-connected component (scipy.ndimage.label) of the free cells that holds
   the take-off area: the free cell nearest the start point (mission.start, else the world's default start) lifted
   by 1 m, which is off the floor (it must be within 1 m of that point). Free pockets the swarm cannot fly to
   (inside closed rooms, outside the building, above a false ceiling) do not count.
4. Explored. A reachable cell counts as explored when the map knows the voxel at its centre (for a TSDF map,
   `state_at(centre) != unknown`: observed free or occupied).

explored_fraction = explored reachable cells / reachable cells, in [0, 1].

Only the cells' centres are tested, so the fraction is that of a point sample of the reachable volume on a
`resolution` lattice; free space closer than `clearance` to a surface (near walls, under the floor contact) is
not in it even though the camera sees it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage

from swarm.config import SwarmConfig, Vec3
from swarm.sim.worlds import World, mission_volume

START_LIFT_M = 1.0  # the take-off seed is this far above the start point, so not in the floor contact
MAX_SEED_OFFSET_M = 1.0  # the seed cell may be this far from the lifted start point


@dataclass
class ReachableSpace:
    origin: np.ndarray  # (3,) world corner of cell (0, 0, 0): the volume's lo
    resolution: float  # cell edge, metres
    mask: np.ndarray  # (nx, ny, nz) bool: reachable cells
    centres: np.ndarray  # (N, 3) world centres of the reachable cells

    @property
    def volume_m3(self) -> float:
        return len(self.centres) * self.resolution**3


def reachable_free_space(
    world: World, lo: ArrayLike, hi: ArrayLike, resolution: float, start: Vec3, clearance: float
) -> ReachableSpace:
    """The reachable free cells of [lo, hi) (see the module docstring); ValueError when the start has none."""
    if resolution <= 0:
        raise ValueError("resolution must be positive")
    lo_a, hi_a = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    shape = tuple(int(n) for n in np.maximum(np.ceil((hi_a - lo_a) / resolution - 1e-9), 0))
    axes = [lo_a[i] + (np.arange(shape[i]) + 0.5) * resolution for i in range(3)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    free = world.distance(centres) >= clearance if len(centres) else np.zeros(0, dtype=bool)
    free[free] = ~world.is_inside_solid(centres[free])  # only far cells need the (costlier) parity test

    seed_point = np.asarray(start, dtype=np.float64) + [0.0, 0.0, START_LIFT_M]
    candidates = np.flatnonzero(free)
    if len(candidates) == 0:
        raise ValueError(f"no free cell of {clearance:g} m clearance in the volume {lo_a} - {hi_a}")
    gap = np.linalg.norm(centres[candidates] - seed_point, axis=1)
    if gap.min() > MAX_SEED_OFFSET_M:
        raise ValueError(f"no free cell within {MAX_SEED_OFFSET_M:g} m of the take-off point {tuple(seed_point)}")
    seed = np.unravel_index(candidates[np.argmin(gap)], shape)

    labels, _ = ndimage.label(free.reshape(shape))  # default structure: 6-connectivity
    mask = labels == labels[seed]
    return ReachableSpace(lo_a, float(resolution), mask, centres[mask.ravel()])


def mission_reachable_space(world: World, config: SwarmConfig) -> ReachableSpace:
    """`reachable_free_space` with the mission's defaults: volume, planning resolution, start, drone radius."""
    lo, hi = mission_volume(world, config.mission.volume)
    start = config.mission.start if config.mission.start is not None else world.default_start
    return reachable_free_space(world, lo, hi, config.mapping.planning_resolution_m, start, config.sim.drone_radius_m)


def explored_fraction(space: ReachableSpace, is_known: Callable[[np.ndarray], np.ndarray]) -> float:
    """Share of the reachable cells whose centre the map knows; is_known maps (N, 3) points to (N,) bool."""
    if len(space.centres) == 0:
        return 0.0
    known = np.asarray(is_known(space.centres), dtype=bool)
    if known.shape != (len(space.centres),):
        raise ValueError(f"is_known returned shape {known.shape} for {len(space.centres)} points")
    return float(np.count_nonzero(known)) / len(space.centres)
