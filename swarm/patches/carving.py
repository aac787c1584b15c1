"""The blocks one depth frame updates: the surface band plus the free space in front of it.

Open3D's `VoxelBlockGrid.integrate` only updates the blocks it is given, and its own block finder
(`compute_unique_block_coordinates`) returns the blocks within the truncation band of the measured surface:
free space between the camera and the surface would then never become known. So the list is computed here:

- surface band: every block touched by the cube of half-side `truncation` around each measured point;
- free space: every block crossed by a sub-sampled set of camera rays, from the camera to depth + truncation.
  Rays are taken every `stride` pixels, the stride chosen so that neighbouring rays are at most half a block
  apart at max range, and each ray is sampled at least every half block (a block that a ray only clips over a
  shorter chord can be missed; on the office flight that is under 1 % of the blocks, at their corners).

Pixels without a return (depth 0, non-finite or beyond max range) carve nothing, as Open3D's kernel skips them.
Ray pixels go through pixel centres (u + 0.5, v + 0.5), the convention of `swarm.sim.camera`.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from swarm.patches.lattice import Lattice

_MAX_BITMAP_CELLS = 1 << 24  # above this many candidate cells, deduplicate by sorting instead


def ray_stride(K: np.ndarray, lattice: Lattice, max_range: float) -> int:
    """Pixel stride of the carving rays: neighbouring rays at most half a block apart at max range."""
    focal = min(float(K[0, 0]), float(K[1, 1]))
    pixel_at_range = max_range / focal
    return max(1, int(math.floor(0.5 * lattice.block_size / pixel_at_range)))


@lru_cache(maxsize=16)
def _ray_pixels(h: int, w: int, step: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the carving rays: every `step` pixels, plus the last row and column."""
    return np.union1d(np.arange(0, h, step), [h - 1]), np.union1d(np.arange(0, w, step), [w - 1])


@lru_cache(maxsize=16)
def _pixel_rays(h: int, w: int, fx: float, fy: float, cx: float, cy: float) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame x/z and y/z of every pixel centre, flattened row-major (float32)."""
    v, u = np.mgrid[0:h, 0:w]
    return ((u.ravel() + 0.5 - cx) / fx).astype(np.float32), ((v.ravel() + 0.5 - cy) / fy).astype(np.float32)


def frame_blocks(
    depth: np.ndarray,
    K: np.ndarray,
    T_lattice_cam: np.ndarray,
    lattice: Lattice,
    max_range: float,
    stride: int | None = None,
) -> np.ndarray:
    """(N,3) int32 unique block keys (sorted) that a frame updates; the pose is in the lattice frame (no origin)."""
    depth = np.ascontiguousarray(depth, dtype=np.float32)
    h, w = depth.shape
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    rot, centre = T_lattice_cam[:3, :3], T_lattice_cam[:3, 3]
    block, trunc = lattice.block_size, lattice.truncation_m
    per_axis = int(math.ceil(2 * trunc / block)) + 1  # blocks a +-trunc interval can touch along one axis

    # Every candidate lies within `reach` of the camera on each axis: a bitmap over that box deduplicates cheaply.
    corner = math.hypot(max(cx, w - cx) / fx, max(cy, h - cy) / fy, 1.0)
    reach = (max_range + trunc) * corner + trunc
    kmin = np.floor((centre - reach) / block).astype(np.int64)
    extent = np.floor((centre + reach) / block).astype(np.int64) - kmin + per_axis + 1
    cells = int(np.prod(extent))
    if cells * per_axis**3 > _MAX_BITMAP_CELLS:
        return _frame_blocks_sorted(depth, K, T_lattice_cam, lattice, max_range, stride)
    sx, sy = int(extent[1] * extent[2]), int(extent[2])
    mark = np.zeros(cells, dtype=bool)

    # Surface band: per point, the first block touched on each axis and how many more; deduplicate those
    # (block, counts) pairs first, then expand the few unique ones.
    flat = depth.ravel()
    valid = (flat > 0) & (flat <= max_range)  # NaN fails both
    if not valid.any():
        return np.zeros((0, 3), dtype=np.int32)
    z = flat[valid]
    xn, yn = _pixel_rays(h, w, fx, fy, cx, cy)
    xn, yn = xn[valid], yn[valid]
    inv_block, trunc32 = np.float32(1.0 / block), np.float32(trunc)
    code = np.zeros(len(z), dtype=np.int32)
    counts = np.zeros(len(z), dtype=np.int32)
    for a, stride_a in enumerate((sx, sy, 1)):
        p = (np.float32(rot[a, 0]) * xn + np.float32(rot[a, 1]) * yn + np.float32(rot[a, 2])) * z
        p += np.float32(centre[a] - kmin[a] * block)  # relative to the bitmap's corner: never negative
        lo = ((p - trunc32) * inv_block).astype(np.int32)
        code += lo * stride_a
        counts = counts * per_axis + (((p + trunc32) * inv_block).astype(np.int32) - lo)
    pairs = np.zeros(cells * per_axis**3, dtype=bool)
    pairs[code * per_axis**3 + counts] = True
    cell, counts = np.divmod(np.flatnonzero(pairs), per_axis**3)
    nx, rest = np.divmod(counts, per_axis * per_axis)
    ny, nz = np.divmod(rest, per_axis)
    for jx in range(per_axis):
        for jy in range(per_axis):
            for jz in range(per_axis):
                sel = (nx >= jx) & (ny >= jy) & (nz >= jz)
                mark[cell[sel] + (jx * sx + jy * sy + jz)] = True

    # Free space: sub-sampled rays from the camera to depth + truncation, one sample every half block or less.
    rows, cols = _ray_pixels(h, w, stride or ray_stride(K, lattice, max_range))
    sub = depth[np.ix_(rows, cols)]
    rv, ru = np.nonzero((sub > 0) & (sub <= max_range))
    if len(rv):
        rx, ry = (cols[ru] + 0.5 - cx) / fx, (rows[rv] + 0.5 - cy) / fy
        dirs = [rot[a, 0] * rx + rot[a, 1] * ry + rot[a, 2] for a in range(3)]
        length = sub[rv, ru].astype(np.float64) + trunc  # in units of the camera-z == 1 direction
        norm = np.sqrt(dirs[0] ** 2 + dirs[1] ** 2 + dirs[2] ** 2)
        samples = np.ceil(length * norm / (0.5 * block)).astype(np.int64) + 1  # per ray, both ends included
        ray = np.repeat(np.arange(len(rv)), samples)
        first = np.cumsum(samples) - samples
        t = (np.arange(len(ray)) - first[ray]) * (length / (samples - 1))[ray]
        index = np.zeros(len(t), dtype=np.int64)
        for a, stride_a in enumerate((sx, sy, 1)):
            k = ((centre[a] - kmin[a] * block + dirs[a][ray] * t) * (1.0 / block)).astype(np.int64)  # >= 0: floor
            index += k * stride_a
        mark[index] = True

    found = np.flatnonzero(mark)
    keys = np.stack(np.unravel_index(found, tuple(int(e) for e in extent)), axis=1) + kmin
    return keys.astype(np.int32)


def _frame_blocks_sorted(
    depth: np.ndarray, K: np.ndarray, T: np.ndarray, lattice: Lattice, max_range: float, stride: int | None
) -> np.ndarray:
    """The same block list as `frame_blocks`, deduplicated by sorting (for ranges too large for a bitmap)."""
    h, w = depth.shape
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    block, trunc = lattice.block_size, lattice.truncation_m
    vs, us = np.nonzero(np.isfinite(depth) & (depth > 0) & (depth <= max_range))
    if len(vs) == 0:
        return np.zeros((0, 3), dtype=np.int32)
    z = depth[vs, us].astype(np.float64)
    rays = np.stack([(us + 0.5 - cx) / fx, (vs + 0.5 - cy) / fy, np.ones_like(z)], axis=1) @ T[:3, :3].T
    points = T[:3, 3] + rays * z[:, None]
    lo = np.floor((points - trunc) / block).astype(np.int64)
    hi = np.floor((points + trunc) / block).astype(np.int64)
    spans = [np.minimum(lo + j, hi) for j in range(int(math.ceil(2 * trunc / block)) + 1)]
    keys = [np.stack([a[:, 0], b[:, 1], c[:, 2]], axis=1) for a in spans for b in spans for c in spans]
    rows, cols = _ray_pixels(h, w, stride or ray_stride(K, lattice, max_range))
    pick = np.isin(vs, rows) & np.isin(us, cols)
    length = (z[pick] + trunc)[:, None] * np.linspace(0.0, 1.0, 64)[None, :]
    samples = T[:3, 3] + rays[pick][:, None, :] * length[:, :, None]
    keys.append(np.floor(samples.reshape(-1, 3) / block).astype(np.int64))
    return unique_keys(np.concatenate(keys))


def unique_keys(keys: np.ndarray) -> np.ndarray:
    """Sorted unique rows of an (N,3) integer key array, as int32 (x slowest, z fastest)."""
    if len(keys) == 0:
        return np.zeros((0, 3), dtype=np.int32)
    return np.unique(np.asarray(keys, dtype=np.int64), axis=0).astype(np.int32)
