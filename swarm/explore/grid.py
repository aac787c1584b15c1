"""A 3D occupancy grid in the world frame (z-up, metres) and the geometric queries a planner needs.

Cell (i, j, k) is the cube `origin + [i, i+1) x [j, j+1) x [k, k+1) * resolution`. Queries read `occupied` only:
unknown space is decided once, by `inflate(unknown_is_occupied=...)`, which folds it into the blocked set or
not. A point outside the grid is never free.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage

# Cell-boundary crossings closer than this (in segment parameter) are one crossing: a segment through a cell
# corner must not be split at a rounding-error sliver that lands in a neighbouring cell.
_CROSSING_MERGE_T = 1e-9


@dataclass
class OccupancyGrid:
    origin: np.ndarray  # (3,) world coordinates of the corner of cell (0, 0, 0)
    resolution: float  # cell edge, metres
    occupied: np.ndarray  # (nx, ny, nz) bool
    unknown: np.ndarray | None = None  # (nx, ny, nz) bool; None when every cell is known

    def __post_init__(self) -> None:
        self.origin = np.asarray(self.origin, dtype=float).reshape(3)
        self.resolution = float(self.resolution)
        if not self.resolution > 0:
            raise ValueError(f"grid resolution must be positive, got {self.resolution}")
        self.occupied = np.asarray(self.occupied, dtype=bool)
        if self.occupied.ndim != 3:
            raise ValueError(f"occupied must be a 3D array, got shape {self.occupied.shape}")
        if self.unknown is not None:
            self.unknown = np.asarray(self.unknown, dtype=bool)
            if self.unknown.shape != self.occupied.shape:
                raise ValueError(f"unknown has shape {self.unknown.shape}, occupied {self.occupied.shape}")

    @property
    def shape(self) -> tuple[int, int, int]:
        nx, ny, nz = self.occupied.shape
        return nx, ny, nz

    def index_of(self, p: ArrayLike) -> tuple[int, int, int] | None:
        """The cell containing world point `p`, or None when `p` is outside the grid."""
        idx = self.indices_of(np.asarray(p, dtype=float).reshape(1, 3))[0]
        if not self._inside(idx[None, :])[0]:
            return None
        i, j, k = (int(v) for v in idx)
        return i, j, k

    def centre_of(self, idx: ArrayLike) -> np.ndarray:
        """World coordinates of the centre of cell `idx` (any integer index, in the grid or not)."""
        return self.origin + (np.asarray(idx, dtype=float) + 0.5) * self.resolution

    def indices_of(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) cell indices of (n, 3) world points; may lie outside the grid."""
        cells = np.floor((np.asarray(points, dtype=float) - self.origin) / self.resolution)
        # NaN/inf points map to -1: outside every grid.
        cells[~np.isfinite(cells)] = -1
        return cells.astype(np.int64)

    def points_are_free(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: each of the (n, 3) world points lies in a free cell of the grid."""
        idx = self.indices_of(points)
        inside = self._inside(idx)
        free = np.zeros(len(idx), dtype=bool)
        i, j, k = idx[inside].T
        free[inside] = ~self.occupied[i, j, k]
        return free

    def is_free(self, p: ArrayLike) -> bool:
        return bool(self.points_are_free(np.asarray(p, dtype=float).reshape(1, 3))[0])

    def segment_is_free(self, a: ArrayLike, b: ArrayLike) -> bool:
        """Every cell the segment a-b passes through is free.

        Exact traversal rather than fixed-step sampling: one probe point between each pair of consecutive
        cell-boundary crossings, so no cell is skipped however thinly it is clipped (this subsumes sampling
        at resolution/2). Touching only an edge or corner of a cell does not count as passing through it.
        """
        a_cells = (np.asarray(a, dtype=float).reshape(3) - self.origin) / self.resolution
        b_cells = (np.asarray(b, dtype=float).reshape(3) - self.origin) / self.resolution
        delta = b_cells - a_cells
        crossings = [np.array([0.0, 1.0])]
        for axis in range(3):
            if delta[axis] == 0.0:
                continue
            lo, hi = sorted((a_cells[axis], b_cells[axis]))
            boundaries = np.arange(np.floor(lo) + 1.0, np.ceil(hi))
            crossings.append((boundaries - a_cells[axis]) / delta[axis])
        t = np.unique(np.concatenate(crossings))
        t = t[np.concatenate(([True], np.diff(t) > _CROSSING_MERGE_T))]
        probes_t = (t[:-1] + t[1:]) / 2 if len(t) > 1 else t
        probes = self.origin + (a_cells + probes_t[:, None] * delta) * self.resolution
        return bool(self.points_are_free(probes).all())

    def nearest_free(self, p: ArrayLike, max_radius: float) -> np.ndarray | None:
        """Centre of the free cell closest to `p` within `max_radius` metres, or None."""
        p = np.asarray(p, dtype=float).reshape(3)
        lo = np.maximum(np.floor((p - max_radius - self.origin) / self.resolution), 0).astype(int)
        hi = np.minimum(np.floor((p + max_radius - self.origin) / self.resolution) + 1, self.shape).astype(int)
        if np.any(hi <= lo):
            return None
        window = ~self.occupied[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
        free_idx = np.argwhere(window) + lo
        if len(free_idx) == 0:
            return None
        centres = self.centre_of(free_idx)
        dist = np.linalg.norm(centres - p, axis=1)
        best = int(np.argmin(dist))
        return centres[best] if dist[best] <= max_radius else None

    def inflate(self, radius: float, unknown_is_occupied: bool = False) -> OccupancyGrid:
        """A grid whose `occupied` is the blocked set for a body of `radius` metres.

        Blocked = every cell that has any point closer than `radius` to an occupied cell (and to an unknown
        cell when `unknown_is_occupied`). Rasterising conservatively means every point of every free cell,
        not only its centre, has at least `radius` clearance, so straight segments through free cells are
        safe. Obstacles grow by `radius` rounded up to whole cells: by less than `radius + resolution`.
        Unknown cells not folded into the blocked set stay in `unknown` of the result, and plan as free.
        """
        blocked = self.occupied.copy()
        if unknown_is_occupied and self.unknown is not None:
            blocked |= self.unknown
        if radius > 0 and blocked.any():
            # Cell-centre distance < radius, then one more ring of cells: together exactly the cells whose
            # cube comes closer than `radius` to an obstacle cube (Minkowski sum of the ball and a 3x3x3).
            centre_dist = ndimage.distance_transform_edt(~blocked)
            near = centre_dist < radius / self.resolution - 1e-9
            blocked = ndimage.binary_dilation(near, structure=np.ones((3, 3, 3), dtype=bool))
        unknown = None
        if self.unknown is not None and not unknown_is_occupied:
            unknown = self.unknown & ~blocked
        return OccupancyGrid(self.origin.copy(), self.resolution, blocked, unknown)

    def _inside(self, idx: np.ndarray) -> np.ndarray:
        return np.all((idx >= 0) & (idx < np.asarray(self.shape)), axis=1)
