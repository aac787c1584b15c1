"""A 3D occupancy grid in the world frame (z-up, metres) and the geometric queries a planner needs.

Cell (i, j, k) is the cube `origin + [i, i+1) x [j, j+1) x [k, k+1) * resolution`. Queries read `occupied` only:
unknown space is decided once, by `inflate(unknown_is_occupied=...)`, which folds it into the blocked set or
not. A point outside the grid is never free.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage

# Cell-boundary crossings closer than this (in segment parameter) are one crossing: a segment through a cell
# corner must not be split at a rounding-error sliver that lands in a neighbouring cell.
_CROSSING_MERGE_T = 1e-9
# Segments crossing more cells than this are looked up with numpy; shorter ones in plain Python, which avoids
# numpy's per-call overhead (a one-cell check is ~4x faster; break-even near 100 cells, measured).
_PYTHON_PROBE_LIMIT = 96


@dataclass
class OccupancyGrid:
    origin: np.ndarray  # (3,) world coordinates of the corner of cell (0, 0, 0)
    resolution: float  # cell edge, metres
    occupied: np.ndarray  # (nx, ny, nz) bool
    unknown: np.ndarray | None = None  # (nx, ny, nz) bool; None when every cell is known
    # (nx, ny, nz) bool: free cells with room to spare (a wider clearance), which the planner prefers; None: all
    roomy: np.ndarray | None = None

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
        if self.roomy is not None:
            self.roomy = np.asarray(self.roomy, dtype=bool) & ~self.occupied
            if self.roomy.shape != self.occupied.shape:
                raise ValueError(f"roomy has shape {self.roomy.shape}, occupied {self.occupied.shape}")

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
        indices: np.ndarray = cells.astype(np.int64)
        return indices

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

    def segment_is_free(self, a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray) -> bool:
        """Every cell the segment a-b passes through is free (and in the grid).

        Exact traversal rather than fixed-step sampling: one probe point between each pair of consecutive
        cell-boundary crossings, so no cell is skipped however thinly it is clipped (this subsumes sampling
        at resolution/2). Touching only an edge or corner of a cell does not count as passing through it.
        """
        start, end = self._cell_coords(a), self._cell_coords(b)
        if start is None or end is None:
            return False
        delta = [e - s for s, e in zip(start, end)]
        crossings = [0.0, 1.0]
        for s, e, d in zip(start, end, delta):
            if d != 0.0:
                crossings.extend((k - s) / d for k in range(math.floor(min(s, e)) + 1, math.ceil(max(s, e))))
        crossings.sort()
        probes_t = [(t0 + t1) * 0.5 for t0, t1 in zip(crossings, crossings[1:]) if t1 - t0 > _CROSSING_MERGE_T]
        if len(probes_t) > _PYTHON_PROBE_LIMIT:
            ts = np.array(probes_t)[:, None]
            cells = np.floor(np.array(start) + ts * np.array(delta)).astype(np.int64)
            if cells.min() < 0 or (cells.max(axis=0) >= self.occupied.shape).any():
                return False
            return not self.occupied[cells[:, 0], cells[:, 1], cells[:, 2]].any()
        (sx, sy, sz), (dx, dy, dz), (nx, ny, nz) = start, delta, self.shape
        occupied = self.occupied
        for t in probes_t:
            i, j, k = math.floor(sx + t * dx), math.floor(sy + t * dy), math.floor(sz + t * dz)
            if not (0 <= i < nx and 0 <= j < ny and 0 <= k < nz) or occupied[i, j, k]:
                return False
        return True

    def _cell_coords(self, p: Sequence[float] | np.ndarray) -> tuple[float, float, float] | None:
        """`p` in units of cells from the grid origin, as plain floats; None when not finite."""
        ox, oy, oz = self.origin.tolist()
        r = self.resolution
        coords = ((float(p[0]) - ox) / r, (float(p[1]) - oy) / r, (float(p[2]) - oz) / r)
        return coords if all(map(math.isfinite, coords)) else None

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

    def with_balls_blocked(self, centres: Sequence[Sequence[float]], radius: float) -> OccupancyGrid:
        """This grid with the cells within `radius` plus half a cell diagonal of any of `centres` blocked too
        (every cell whose cube comes closer than `radius`): a path planned on the result keeps at least `radius`
        from each centre, such as a drone parked in the way."""
        blocked = self.occupied.copy()
        reach = radius + math.sqrt(3.0) / 2.0 * self.resolution  # cell centre to the farthest point of its cube
        for centre in centres:
            c = np.asarray(centre, dtype=float)
            low = np.maximum(np.floor((c - reach - self.origin) / self.resolution).astype(int), 0)
            high = np.minimum(np.ceil((c + reach - self.origin) / self.resolution).astype(int), self.shape)
            if np.any(low >= high):
                continue
            axes = [self.origin[a] + (np.arange(low[a], high[a]) + 0.5) * self.resolution - c[a] for a in range(3)]
            dx, dy, dz = np.meshgrid(*axes, indexing="ij")
            near = dx * dx + dy * dy + dz * dz < reach * reach
            blocked[low[0] : high[0], low[1] : high[1], low[2] : high[2]] |= near
        unknown = None if self.unknown is None else self.unknown & ~blocked
        return OccupancyGrid(self.origin.copy(), self.resolution, blocked, unknown, self.roomy)

    def _inside(self, idx: np.ndarray) -> np.ndarray:
        inside: np.ndarray = np.all((idx >= 0) & (idx < np.asarray(self.shape)), axis=1)
        return inside
