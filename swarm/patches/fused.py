"""The fused map: every held patch summed into one TSDF over the bounded mission volume.

Per voxel it keeps W = sum of the patches' quantised weights (int32, in weight units) and S = sum of
weight * quantised tsdf (int32, promoted to int64 once a voxel could reach 2^31 / 127 units); the fused tsdf is
S / (127 W). Integer sums make fusion exactly commutative and associative: agents that hold the same patch ids
hold bit-identical arrays whatever the arrival order, and a temporary contribution (the open patch) is removed
exactly. With uncapped sums this equals one TSDF integrated from all the frames, up to the int8 quantisation of
each patch's tsdf.

Storage is a block pool (rows of R^3 voxels) with a dense block-index grid over the mission volume; blocks of
a patch outside that volume are ignored.

Occupancy grids whose cells are whole f^3 voxels of one block (the planning grid at 0.2 m and the fine one at the
voxel size, on a lattice whose origin is on the grid) are kept from one call to the next and updated from the
blocks whose sums changed since (each block row carries the clock tick of its last change): a decision costs what
changed, the open patch included and removed again, not the whole building. The result is the same array a full
computation gives (tests/patches/test_occupancy_incremental.py); only the copy handed out is O(cells).

Classification (after Hardouin 2022, section 1.2): known = W >= known threshold; free = known and tsdf > 0;
occupied = observed (W > 0) and tsdf <= 0, known or not; unknown otherwise. An obstacle counts as soon as anything
saw it there: under the "dropoff" weight law a thin wall seen only edge-on gets weights far below the threshold,
and requiring the threshold let such a wall read as free space.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import zstandard

from swarm.patches.lattice import Lattice
from swarm.patches.patch import TSDF_SCALE, Patch, PatchId, TsdfArrays, VoxelBlocks, pack_blocks

UNKNOWN, FREE, OCCUPIED = 0, 1, 2
_EPS = 1e-9
_INT32_SAFE_WEIGHT = (2**31 - 1) // 127  # while every W stays below this, S = sum(w * q) fits int32
# Passes over the whole map (occupancy updates, digest, whole-map baseline) take this many block rows at a time:
# a hall map's 17,000 blocks at once made 100-250 MB of temporaries, which malloc then kept.
ROW_CHUNK = 2048
MESH_TILE_BLOCKS = 1024  # blocks meshed at once (`FusedMap.mesh`): about 30 MB of temporaries
_UPPER_OFFSETS = [np.array(o, dtype=np.int32) for o in np.ndindex(2, 2, 2) if any(o)]
CACHED_GRIDS = 4  # occupancy grids kept for incremental update (a decision asks for two: planning and fine)

Bounds = tuple[Sequence[float] | np.ndarray, Sequence[float] | np.ndarray]


class FusedMap:
    def __init__(self, lattice: Lattice, bounds: Bounds, known_weight: float = 1.0, initial_blocks: int = 1024) -> None:
        lo, hi = np.asarray(bounds[0], dtype=np.float64), np.asarray(bounds[1], dtype=np.float64)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite(lo) & np.isfinite(hi)) or np.any(lo >= hi):
            raise ValueError(f"bounds must be two finite 3-vectors with lo < hi, got {lo}, {hi}")
        self.lattice = lattice
        self.bounds = (lo, hi)
        self.known_units = lattice.weight_units(known_weight)
        r, v, o = lattice.block_resolution, lattice.voxel_size, lattice.origin_array
        # voxels whose sample point lies in [lo, hi]
        self._vlo = np.ceil((lo - o) / v - _EPS).astype(np.int64)
        self._vhi = np.floor((hi - o) / v + _EPS).astype(np.int64)
        self._kmin = np.floor_divide(self._vlo, r)
        shape = np.floor_divide(self._vhi, r) - self._kmin + 1
        self._grid = np.full(tuple(int(s) for s in shape), -1, dtype=np.int32)
        cap = max(1, min(initial_blocks, self._grid.size))
        self._keys = np.zeros((cap, 3), dtype=np.int32)
        self._weight = np.zeros((cap, lattice.voxels_per_block), dtype=np.int32)
        self._sum = np.zeros((cap, lattice.voxels_per_block), dtype=np.int32)
        self._changed_at = np.zeros(cap, dtype=np.int64)  # per row: the tick of its last change (see module doc)
        self._tick = 0
        self._grids: dict[tuple[Any, ...], _CellCache] = {}  # kept occupancy grids, oldest first
        self._weight_bound = 0  # an upper bound of every voxel's W
        self._count = 0
        self._ids: set[PatchId] = set()

    # --- fusion ----------------------------------------------------------------------------------------------

    def add(self, patch: Patch) -> bool:
        """Fuse a patch once; False (and no change) if its id was already fused. Raises ValueError on a lattice
        mismatch (decode_patch rejects those before they get here)."""
        if patch.id in self._ids:
            return False
        if patch.lattice != self.lattice:
            raise ValueError(f"patch {patch.id} is on another lattice ({patch.lattice.describe()})")
        self._accumulate(patch.blocks, 1)
        self._ids.add(patch.id)
        return True

    @contextmanager
    def including(self, blocks: VoxelBlocks | None) -> Iterator[FusedMap]:
        """This map with `blocks` (e.g. the open patch) added for the duration of the block, then removed exactly."""
        if blocks is None or blocks.block_count == 0:
            yield self
            return
        self._accumulate(blocks, 1)
        try:
            yield self
        finally:
            self._accumulate(blocks, -1)

    def __contains__(self, pid: object) -> bool:
        return pid in self._ids

    @property
    def ids(self) -> frozenset[PatchId]:
        return frozenset(self._ids)

    def _accumulate(self, blocks: VoxelBlocks, sign: int) -> None:
        inside, slots = self._slots(blocks.keys, allocate=True)
        if not len(slots):
            return
        weight = blocks.weight if inside.all() else blocks.weight[inside]
        tsdf = blocks.tsdf if inside.all() else blocks.tsdf[inside]
        if sign > 0:
            self._widen_sums(int(weight.max(initial=0)))
        weighted = np.multiply(weight, tsdf, dtype=self._sum.dtype)
        self._tick += 1
        self._changed_at[slots] = self._tick
        if sign > 0:
            self._weight[slots] += weight
            self._sum[slots] += weighted
        else:
            self._weight[slots] -= weight
            self._sum[slots] -= weighted

    def _widen_sums(self, added_weight: int) -> None:
        self._weight_bound += added_weight
        if self._sum.dtype == np.int64 or self._weight_bound < _INT32_SAFE_WEIGHT:
            return
        self._weight_bound = int(self._weight[: self._count].max(initial=0)) + added_weight
        if self._weight_bound >= _INT32_SAFE_WEIGHT:
            self._sum = self._sum.astype(np.int64)

    def _slots(self, keys: np.ndarray, allocate: bool) -> tuple[np.ndarray, np.ndarray]:
        """(mask of keys inside the grid, their pool rows); unallocated blocks get -1 or a new row."""
        rel = np.asarray(keys, dtype=np.int64) - self._kmin
        inside = np.all((rel >= 0) & (rel < self._grid.shape), axis=1)
        rel = rel[inside]
        slots = self._grid[rel[:, 0], rel[:, 1], rel[:, 2]].astype(np.int64)
        if allocate:
            new = slots < 0
            n_new = int(np.count_nonzero(new))
            if n_new:
                self._reserve(self._count + n_new)
                fresh = np.arange(self._count, self._count + n_new)
                slots[new] = fresh
                self._grid[rel[new, 0], rel[new, 1], rel[new, 2]] = fresh
                self._keys[fresh] = np.asarray(keys, dtype=np.int32)[inside][new]
                self._count += n_new
        return inside, slots

    def _held(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(indices into `keys` of the blocks held here, their pool rows)."""
        inside, slots = self._slots(keys, allocate=False)
        return np.flatnonzero(inside)[slots >= 0], slots[slots >= 0]

    def _reserve(self, needed: int) -> None:
        cap = len(self._keys)
        if needed <= cap:
            return
        cap = max(needed, 2 * cap)
        grown = []
        for array in (self._keys, self._weight, self._sum):
            bigger = np.zeros((cap, array.shape[1]), dtype=array.dtype)
            bigger[: self._count] = array[: self._count]
            grown.append(bigger)
        self._keys, self._weight, self._sum = grown
        changed_at = np.zeros(cap, dtype=np.int64)
        changed_at[: self._count] = self._changed_at[: self._count]
        self._changed_at = changed_at

    # --- queries ---------------------------------------------------------------------------------------------

    @property
    def block_count(self) -> int:
        return self._count

    @property
    def resident_bytes(self) -> int:
        """Bytes of memory the map holds: its block rows in use (the pool's spare rows are never written, so
        never resident), the block-index grid and the kept occupancy grids."""
        row = self._keys.itemsize * 3 + (self._weight.itemsize + self._sum.itemsize) * self._weight.shape[1] + 8
        kept = sum(cache.cells.nbytes + cache.seen.nbytes for cache in self._grids.values())
        return self._count * row + self._grid.nbytes + kept

    @property
    def voxel_count(self) -> int:
        """Observed voxels (W > 0)."""
        return int(np.count_nonzero(self._weight[: self._count]))

    @property
    def known_count(self) -> int:
        return int(np.count_nonzero(self._weight[: self._count] >= self.known_units))

    @property
    def known_fraction(self) -> float:
        """Known voxels / all lattice voxels of the mission volume."""
        keys = self._keys[: self._count].astype(np.int64)
        r = self.lattice.block_resolution
        steps = np.arange(r)
        ok = [
            ((keys[:, a : a + 1] * r + steps) >= self._vlo[a]) & ((keys[:, a : a + 1] * r + steps) <= self._vhi[a])
            for a in range(3)
        ]
        inside = (ok[2][:, :, None, None] & ok[1][:, None, :, None] & ok[0][:, None, None, :]).reshape(len(keys), r**3)
        known = self._weight[: self._count] >= self.known_units
        total = int(np.prod(self._vhi - self._vlo + 1))
        return int(np.count_nonzero(known & inside)) / total

    def novelty(self, keys: np.ndarray) -> float:
        """The share of (N,3) block keys inside the map's volume that hold no observed voxel here yet (0 for none
        inside)."""
        _, slots = self._slots(keys, allocate=False)  # the rows of the keys inside, -1 where none is held
        if not len(slots):
            return 0.0
        observed = np.count_nonzero(self._weight[slots[slots >= 0]].any(axis=1))
        return float(len(slots) - observed) / len(slots)

    def sums(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(W, S) as int64 (M, R^3) for (M,3) block keys: zero for blocks not held here or outside the volume."""
        weight = np.zeros((len(keys), self.lattice.voxels_per_block), dtype=np.int64)
        total = np.zeros_like(weight)
        at, rows = self._held(keys)
        weight[at], total[at] = self._weight[rows], self._sum[rows]
        return weight, total

    def observed_blocks(self, keys: np.ndarray) -> np.ndarray:
        """(M,) bool: which of (M,3) block keys hold an observed voxel here."""
        observed = np.zeros(len(keys), dtype=bool)
        at, rows = self._held(keys)
        observed[at] = self._weight[rows].any(axis=1)
        return observed

    def add_blocks(self, blocks: VoxelBlocks) -> None:
        """Add blocks that are no patch (no id, so nothing to hold or fuse once): for a map used as an
        accumulator (`swarm.patches.unshared`), never for the fused map."""
        self._accumulate(blocks, 1)

    def clear_voxels(self, keys: np.ndarray, voxels: np.ndarray) -> None:
        """Set W and S to 0 at the (M, R^3) mask `voxels` of (M,3) block keys (blocks not held: nothing to do)."""
        at, rows = self._held(keys)
        if not len(rows):
            return
        keep = ~voxels[at]
        self._weight[rows] *= keep
        self._sum[rows] *= keep
        self._tick += 1
        self._changed_at[rows] = self._tick

    def addresses(self, points: np.ndarray) -> VoxelAddresses:
        """Where the voxels nearest to (N,3) world points lie in any map of this lattice and bounds: `state_at`
        takes them in place of the points, for points asked about again and again (the observer's reachable
        cells: mapping 626,000 points to their voxels and blocks was most of a query's 60 ms)."""
        keys, flat = self.lattice.voxel_to_block(self.lattice.point_to_voxel(points))
        rel = keys - self._kmin
        inside = np.flatnonzero(np.all((rel >= 0) & (rel < self._grid.shape), axis=1))
        block = np.ravel_multi_index(tuple(rel[inside].T), self._grid.shape)
        return VoxelAddresses(len(keys), inside, block, flat[inside], self._grid.shape, tuple(self._kmin.tolist()))

    def state_at(self, points: np.ndarray | VoxelAddresses) -> np.ndarray:
        """(N,) uint8 state (UNKNOWN, FREE, OCCUPIED) of the voxels nearest to (N,3) world points (or to the points
        whose `addresses` these are)."""
        at = points if isinstance(points, VoxelAddresses) else self.addresses(points)
        if at.grid_shape != self._grid.shape or at.kmin != tuple(self._kmin.tolist()):
            raise ValueError("voxel addresses of a map with other bounds")
        slots = self._grid.ravel()[at.block]
        held = slots >= 0
        rows, cols, where = slots[held], at.voxel[held], at.inside[held]
        weight = np.zeros(at.count, dtype=np.int64)
        total = np.zeros(at.count, dtype=np.int64)
        weight[where] = self._weight[rows, cols]
        total[where] = self._sum[rows, cols]
        return _classify(weight, total, self.known_units)

    def block_keys(self) -> np.ndarray:
        """(M,3) int32 keys of the blocks with an observed voxel, sorted."""
        return self._observed_rows()[0]

    def arrays(self, within: np.ndarray | None = None) -> TsdfArrays:
        """The fused TSDF as float arrays (blocks with an observed voxel, keys sorted): tsdf = S / (127 W),
        weight = W in the lattice's weight (W units * unit). `within`: only these block keys ((K,3))."""
        keys, rows = self._observed_rows(within)
        return self._float_arrays(keys, self._weight[rows], self._sum[rows])

    def _float_arrays(self, keys: np.ndarray, weight: np.ndarray, total: np.ndarray) -> TsdfArrays:
        with np.errstate(invalid="ignore", divide="ignore"):
            tsdf = np.where(weight > 0, total / (TSDF_SCALE * weight.astype(np.float64)), 0.0)
        return TsdfArrays(keys, tsdf.astype(np.float32), (weight * self.lattice.weight_unit).astype(np.float32))

    def _observed_rows(self, within: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(sorted keys, pool rows) of the blocks with an observed voxel (of `within` only, if given)."""
        n = self._count
        rows = np.flatnonzero(self._weight[:n].any(axis=1))
        if within is not None:
            rows = rows[rows_in(self._keys[rows], np.asarray(within, dtype=np.int32).reshape(-1, 3))]
        keys = self._keys[rows]
        order = np.lexsort((keys[:, 2], keys[:, 1], keys[:, 0]))
        return keys[order], rows[order]

    def digest(self) -> str:
        """A hash of the lattice and the fused arrays; equal maps have equal digests."""
        keys, rows = self._observed_rows()
        h = hashlib.blake2b(digest_size=16)
        h.update(self.lattice.describe().encode())
        h.update(_little_endian(keys))
        for pool in (self._weight, self._sum):  # one stream per array, hashed ROW_CHUNK rows at a time
            for chunk in _chunks(rows):
                h.update(_little_endian(pool[chunk]))
        return h.hexdigest()

    def wire_size(self, level: int = 3) -> int:
        """Bytes of this whole map compressed the way a patch is (`pack_blocks` with uint16 weights, zstd):
        what sending the whole fused map once would cost, the baseline patch sharing is measured against."""
        return compressed_size(self.wire_raw(), level)

    def wire_raw(self) -> bytes:
        """The whole map's arrays as a patch lays them out, before compression (`wire_size` compresses them;
        a caller may do that on another thread, off the map's)."""
        keys, rows = self._observed_rows()
        tsdf = np.empty((len(rows), self.lattice.voxels_per_block), dtype=np.int8)
        weight = np.empty(tsdf.shape, dtype=np.uint16)
        start = 0
        for chunk in _chunks(rows):
            w, total = self._weight[chunk], self._sum[chunk]
            end = start + len(chunk)
            tsdf[start:end] = np.where(w > 0, np.rint(total / np.maximum(w, 1)), 0)
            weight[start:end] = np.minimum(w, 65535)
            start = end
        return pack_blocks(keys, tsdf, weight)

    def occupancy_grid(
        self,
        resolution: float,
        lo: Sequence[float] | np.ndarray | None = None,
        hi: Sequence[float] | np.ndarray | None = None,
        min_known: float = 1.0,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(corner of cell (0,0,0), uint8 (nx,ny,nz) states) of a coarse grid over [lo, hi) (default: the bounds).

        A fine voxel belongs to the cell holding its sample point. A cell is OCCUPIED if any of its voxels is
        occupied, FREE if at least `min_known` of its voxels are known (by default all: a cell is only declared
        free when it was entirely seen) and none is occupied, UNKNOWN otherwise.
        """
        if not resolution > 0:
            raise ValueError("resolution must be positive")
        if not 0.0 < min_known <= 1.0:
            raise ValueError("min_known must be in (0, 1]")
        lo_ = self.bounds[0] if lo is None else np.asarray(lo, dtype=np.float64)
        hi_ = self.bounds[1] if hi is None else np.asarray(hi, dtype=np.float64)
        shape = np.maximum(np.ceil((hi_ - lo_) / resolution - _EPS).astype(np.int64), 0)
        n_cells = int(np.prod(shape))
        states = np.zeros(n_cells, dtype=np.uint8)
        if n_cells == 0:
            return lo_, states.reshape(tuple(shape))
        aligned = self._aligned_cells(resolution, lo_)
        if aligned is not None:
            f, offset = aligned
            grid_shape = (int(shape[0]), int(shape[1]), int(shape[2]))
            return lo_.copy(), self._occupancy_aligned(f, offset, grid_shape, min_known)
        v, o, r = self.lattice.voxel_size, self.lattice.origin_array, self.lattice.block_resolution

        def cell_of(index: np.ndarray, axis: int) -> np.ndarray:
            cells: np.ndarray = np.floor((o[axis] + index * v - lo_[axis]) / resolution + _EPS).astype(np.int64)
            return cells

        # voxels per cell along each axis
        totals = []
        for axis in range(3):
            first = int(np.ceil((lo_[axis] - o[axis]) / v - _EPS)) - 1
            last = int(np.floor((lo_[axis] + shape[axis] * resolution - o[axis]) / v + _EPS)) + 1
            cells = cell_of(np.arange(first, last + 1), axis)
            cells = cells[(cells >= 0) & (cells < shape[axis])]
            totals.append(np.bincount(cells, minlength=int(shape[axis])))
        total = (totals[0][:, None, None] * totals[1][None, :, None] * totals[2][None, None, :]).ravel()

        keys = self._keys[: self._count].astype(np.int64)
        steps = np.arange(r)
        per_axis_cell, per_axis_ok = [], []
        for axis in range(3):
            c = cell_of(keys[:, axis : axis + 1] * r + steps, axis)
            per_axis_ok.append((c >= 0) & (c < shape[axis]))
            per_axis_cell.append(c)
        touching = per_axis_ok[0].any(axis=1) & per_axis_ok[1].any(axis=1) & per_axis_ok[2].any(axis=1)
        rows = np.flatnonzero(touching)
        cx, cy, cz = (c[rows] for c in per_axis_cell)
        ox, oy, oz = (ok[rows] for ok in per_axis_ok)
        ny, nz = int(shape[1]), int(shape[2])
        # storage order inside a block is [z, y, x]
        flat = (cx[:, None, None, :] * ny + cy[:, None, :, None]) * nz + cz[:, :, None, None]
        ok = oz[:, :, None, None] & oy[:, None, :, None] & ox[:, None, None, :]
        flat, ok = flat.reshape(len(rows), r**3), ok.reshape(len(rows), r**3)
        weight, total_sum = self._weight[rows], self._sum[rows]
        known = ok & (weight >= self.known_units)
        occupied = ok & (weight > 0) & (total_sum <= 0)
        known_per_cell = np.bincount(flat[known], minlength=n_cells)
        occupied_cells = np.zeros(n_cells, dtype=bool)
        occupied_cells[flat[occupied]] = True
        states[(known_per_cell >= min_known * total - _EPS) & (total > 0)] = FREE
        states[occupied_cells] = OCCUPIED
        return lo_.copy(), states.reshape(tuple(int(s) for s in shape))

    def _aligned_cells(self, resolution: float, lo: np.ndarray) -> tuple[int, np.ndarray] | None:
        """(voxels per cell edge f, cell offset of voxel 0 per axis) when every cell is exactly f^3 voxels of one
        block (the usual case: 0.2 m cells on a 0.1 m lattice whose origin sits on the grid); else None."""
        f = resolution / self.lattice.voxel_size
        offset = (self.lattice.origin_array - lo) / resolution
        r = self.lattice.block_resolution
        if abs(f - round(f)) > 1e-6 or round(f) < 1 or r % round(f) or np.any(np.abs(offset - np.rint(offset)) > 1e-6):
            return None
        return int(round(f)), np.rint(offset).astype(np.int64)

    def _occupancy_aligned(
        self, f: int, offset: np.ndarray, shape: tuple[int, int, int], min_known: float = 1.0
    ) -> np.ndarray:
        """`occupancy_grid` by reducing each block's voxels f x f x f at a time: the same states, ~10x faster;
        kept between calls and updated from the rows that changed since (module doc)."""
        key = (f, tuple(int(v) for v in offset), shape, min_known)
        cache = self._grids.pop(key, None)
        if cache is None:
            cache = _CellCache(np.zeros(int(np.prod(shape)), dtype=np.uint8), np.zeros(0, dtype=np.int64))
        self._grids[key] = cache  # the most recently used last
        while len(self._grids) > CACHED_GRIDS:
            del self._grids[next(iter(self._grids))]
        n = self._count
        if len(cache.seen) < n:
            cache.seen = np.concatenate([cache.seen, np.full(n - len(cache.seen), -1, dtype=np.int64)])
        rows = np.flatnonzero(self._changed_at[:n] != cache.seen[:n])
        if len(rows):
            for chunk in _chunks(rows):
                self._write_cells(cache.cells, chunk, f, offset, shape, min_known)
            cache.seen[:n] = self._changed_at[:n]
        return cache.cells.reshape(shape).copy()

    def _write_cells(
        self,
        out: np.ndarray,
        rows: np.ndarray,
        f: int,
        offset: np.ndarray,
        shape: tuple[int, int, int],
        min_known: float,
    ) -> None:
        """Write the cell states of block `rows` into `out`, the flat [x, y, z] cells of the grid."""
        r = self.lattice.block_resolution
        c = r // f  # cells per block edge
        weight, total = self._weight[rows], self._sum[rows]
        known = weight >= self.known_units
        occupied = (weight > 0) & (total <= 0)
        if f == 1:  # a cell is a voxel: nothing to reduce (min_known is in (0, 1]: a known voxel is enough)
            any_occupied, enough_known = occupied, known
        else:
            any_occupied = _reduce_cells(occupied, np.logical_or, r, f)
            if min_known >= 1.0:
                enough_known = _reduce_cells(known, np.logical_and, r, f)
            else:
                enough_known = _reduce_cells(known.astype(np.uint16), np.add, r, f) >= min_known * f**3 - _EPS
        cell_states = np.where(
            any_occupied, np.uint8(OCCUPIED), np.where(enough_known, np.uint8(FREE), np.uint8(UNKNOWN))
        ).reshape(len(rows), c, c, c)
        corner = offset + self._keys[rows].astype(np.int64) * c  # (n, 3) each block's first cell per axis
        whole = np.all((corner >= 0) & (corner + c <= np.array(shape)), axis=1)
        # A block wholly inside the grid: its first cell's index plus a fixed table of its cells' offsets.
        base = (corner[whole, 0] * shape[1] + corner[whole, 1]) * shape[2] + corner[whole, 2]
        out[(base[:, None] + _cell_offsets(c, shape)[None, :]).reshape(-1)] = cell_states[whole].reshape(-1)
        if whole.all():
            return
        part, states = corner[~whole], cell_states[~whole]
        steps = np.arange(c)
        gx, gy, gz = (part[:, a : a + 1] + steps for a in range(3))  # (n, c) cell index per axis
        # cell_states are [z, y, x] within a block (the voxels' storage order); out is [x, y, z]
        flat = (gx[:, None, None, :] * shape[1] + gy[:, None, :, None]) * shape[2] + gz[:, :, None, None]
        inside = (
            ((gz >= 0) & (gz < shape[2]))[:, :, None, None]
            & ((gy >= 0) & (gy < shape[1]))[:, None, :, None]
            & ((gx >= 0) & (gx < shape[0]))[:, None, None, :]
        )
        out[flat[inside]] = states[inside]

    def mesh(self, within: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Marching-cubes surface of the known voxels: (V,3) float64 world vertices, (F,3) int32 triangles;
        `within`: of these blocks only (a triangle that spans two blocks needs both).

        Meshed `MESH_TILE_BLOCKS` blocks at a time, so the temporaries are a tile's, not the map's (whole, a hall
        agent's final mesh took 270 MB more than its flight). Each tile is extracted with the voxels its cubes
        reach in the blocks above it; vertices on a seam come out of both tiles, bit-identical, and are merged."""
        from swarm.patches.meshing import extract_mesh, merge_meshes

        # Open3D's threshold is strict (w > threshold): half a unit below the known threshold
        threshold = (self.known_units - 0.5) * self.lattice.weight_unit
        _, rows = self._observed_rows(within)
        member = np.zeros(self._count, dtype=bool)
        member[rows] = True
        parts = []
        for tile_rows in _chunks(rows, MESH_TILE_BLOCKS):
            tile_keys = self._keys[tile_rows]
            in_tile = np.zeros(self._count, dtype=bool)
            in_tile[tile_rows] = True
            edge_keys, edge_rows, edge_voxels = self._upper_neighbours(tile_keys, member & ~in_tile)
            arrays = self._float_arrays(
                np.concatenate([tile_keys, edge_keys]),
                np.concatenate([self._weight[tile_rows], self._weight[edge_rows] * edge_voxels]),
                np.concatenate([self._sum[tile_rows], self._sum[edge_rows] * edge_voxels]),
            )
            parts.append(extract_mesh(self.lattice, arrays, threshold))
        return merge_meshes(parts)

    def _upper_neighbours(self, keys: np.ndarray, eligible: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The blocks one step up (+x, +y, +z or a mix) of `keys` among the pool rows flagged `eligible`: (keys,
        rows, (M, R^3) mask of the voxels the marching cubes of `keys` reach in them).

        A cube of voxel v spans v + {0,1}^3; across the face to the block at offset o it reaches only the voxels
        with local index 0 along the axes of o. No cube of a block so masked has all eight corners (its corner
        +(1,1,1) inside the block has no local index 0), so the neighbours add no triangle of their own."""
        r = self.lattice.block_resolution
        z, y, x = np.meshgrid(np.arange(r), np.arange(r), np.arange(r), indexing="ij")  # flat order [z, y, x]
        found: list[tuple[np.ndarray, np.ndarray]] = []  # (rows, layer) per offset; no row twice in one offset
        for offset in _UPPER_OFFSETS:
            _, rows = self._held(keys + offset)
            layer = np.ones((r, r, r), dtype=bool)
            for step, local in zip(offset, (x, y, z)):
                if step:
                    layer &= local == 0
            found.append((rows[eligible[rows]], layer.reshape(-1)))
        unique_rows, inverse = np.unique(np.concatenate([rows for rows, _ in found]), return_inverse=True)
        voxels = np.zeros((len(unique_rows), r**3), dtype=bool)
        start = 0
        for rows, layer in found:
            voxels[inverse[start : start + len(rows)]] |= layer
            start += len(rows)
        return self._keys[unique_rows], unique_rows, voxels

    def write_mesh(self, path: str | Path) -> tuple[int, int]:
        """Write the mesh as .ply; returns (vertices, triangles)."""
        from swarm.patches.meshing import write_ply

        vertices, triangles = self.mesh()
        write_ply(path, vertices, triangles)
        return len(vertices), len(triangles)


@dataclass(frozen=True)
class VoxelAddresses:
    """`FusedMap.addresses`: the voxels of `count` points, those inside the map's bounds only."""

    count: int
    inside: np.ndarray  # (M,) indices of the points inside the bounds
    block: np.ndarray  # (M,) their block's flat index in the map's block grid
    voxel: np.ndarray  # (M,) their voxel's flat index in the block
    grid_shape: tuple[int, ...]
    kmin: tuple[int, ...]


@dataclass
class _CellCache:
    """A kept occupancy grid: its flat [x, y, z] cells, and the change tick of each block row when last written."""

    cells: np.ndarray
    seen: np.ndarray


def compressed_size(raw: bytes, level: int = 3) -> int:
    """The zstd-compressed size of `raw` at `level` (patches use 3)."""
    return len(zstandard.ZstdCompressor(level=level).compress(raw))


def _chunks(rows: np.ndarray, size: int | None = None) -> Iterator[np.ndarray]:
    """`rows` `size` (default ROW_CHUNK) at a time: a pass over the whole map's voxels holds one chunk's
    temporaries."""
    size = ROW_CHUNK if size is None else size
    for start in range(0, len(rows), size):
        yield rows[start : start + size]


def _little_endian(array: np.ndarray) -> bytes:
    return np.ascontiguousarray(array).astype(array.dtype.newbyteorder("<"), copy=False).tobytes()


def rows_in(keys: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """Boolean mask of the rows of (M,3) `keys` that are among (K,3) `wanted`."""
    if len(keys) == 0 or len(wanted) == 0:
        return np.zeros(len(keys), dtype=bool)
    as_rows = np.dtype([("x", np.int32), ("y", np.int32), ("z", np.int32)])
    return np.isin(
        np.ascontiguousarray(keys, dtype=np.int32).view(as_rows).ravel(),
        np.ascontiguousarray(wanted, dtype=np.int32).view(as_rows).ravel(),
    )


@lru_cache(maxsize=8)
def _cell_offsets(c: int, shape: tuple[int, int, int]) -> np.ndarray:
    """(c^3,) flat offsets in an [x, y, z] grid of `shape` of a block's c^3 cells, in the block's [z, y, x] order."""
    z, y, x = np.meshgrid(np.arange(c), np.arange(c), np.arange(c), indexing="ij")
    offsets: np.ndarray = ((x * shape[1] + y) * shape[2] + z).reshape(-1).astype(np.int64)
    return offsets


def _reduce_cells(voxels: np.ndarray, combine: np.ufunc, r: int, f: int) -> np.ndarray:
    """(n, c, c, c) [z, y, x] cells of (n, r^3) [z, y, x] block voxels, combining f voxels per axis.

    One axis at a time with strided slices: numpy's multi-axis reductions over such shapes are ~10x slower."""
    n, c = len(voxels), r // f
    shapes = ((n, r, r, c, f), (n, r, c, f, c), (n, c, f, c, c))  # split x, then y, then z
    current = voxels
    for axis, shape in zip((4, 3, 2), shapes):
        split = current.reshape(shape)
        index: list[slice | int] = [slice(None)] * 5
        index[axis] = 0
        acc = split[tuple(index)].copy()
        for i in range(1, f):
            index[axis] = i
            combine(acc, split[tuple(index)], out=acc)
        current = acc
    return current


def _classify(weight: np.ndarray, total: np.ndarray, known_units: int) -> np.ndarray:
    occupied = (weight > 0) & (total <= 0)
    return np.where(occupied, np.uint8(OCCUPIED), np.where(weight >= known_units, np.uint8(FREE), np.uint8(UNKNOWN)))
