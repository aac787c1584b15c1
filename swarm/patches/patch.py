"""Patches: sealed TSDF sub-maps with a unique id.

A patch holds its voxels in the quantised form that travels on the wire, and fusion uses exactly that form:
tsdf as int8 = round(tsdf * 127), weight as unsigned integers in the lattice's weight unit (constant law: uint8
= min(w, 255), exact up to 255 frames; inverse-square law: uint16 in 1/256; drop-off law: uint16 in 1/16, see
`Lattice`). Only blocks with at least one observed voxel are kept; unobserved voxels have weight 0 and tsdf 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import NamedTuple

import numpy as np

from swarm.patches.lattice import Lattice

TSDF_SCALE = 127


class TsdfArrays(NamedTuple):
    """Float blocks as a TSDF backend holds them: keys int32 (M,3) sorted, tsdf float32 (M,R^3) in [-1,1],
    weight float32 (M,R^3)."""

    keys: np.ndarray
    tsdf: np.ndarray
    weight: np.ndarray


@dataclass(frozen=True, order=True)
class PatchId:
    """(producer drone id, producer epoch, sequence number within the epoch); ordered, hashable."""

    producer: int
    epoch: int
    seq: int

    def __post_init__(self) -> None:
        for name in ("producer", "epoch", "seq"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"patch id {name} must be a non-negative int, got {value!r}")

    def __str__(self) -> str:
        return f"{self.producer}.{self.epoch}.{self.seq}"

    @classmethod
    def parse(cls, text: str) -> PatchId:
        parts = text.split(".")
        if len(parts) != 3 or not all(p.isdigit() for p in parts):
            raise ValueError(f"'{text}' is not a patch id (producer.epoch.seq)")
        return cls(int(parts[0]), int(parts[1]), int(parts[2]))


@dataclass(frozen=True)
class FrameSpan:
    """The frames a patch integrates: first and last frame index (inclusive) and their capture times."""

    first: int
    last: int
    t_first: float
    t_last: float

    @property
    def frames(self) -> int:
        return self.last - self.first + 1


@dataclass(frozen=True, eq=False)
class VoxelBlocks:
    """Quantised blocks on a lattice: keys int32 (M,3) unique, tsdf int8 (M,R^3), weight (M,R^3) in weight units."""

    keys: np.ndarray
    tsdf: np.ndarray
    weight: np.ndarray

    def __post_init__(self) -> None:
        m = len(self.keys)
        if self.keys.shape != (m, 3) or self.keys.dtype != np.int32:
            raise ValueError(f"keys must be int32 (M,3), got {self.keys.dtype} {self.keys.shape}")
        if self.tsdf.dtype != np.int8 or self.tsdf.ndim != 2 or len(self.tsdf) != m:
            raise ValueError(f"tsdf must be int8 (M,R^3), got {self.tsdf.dtype} {self.tsdf.shape}")
        if self.weight.shape != self.tsdf.shape or self.weight.dtype.kind != "u":
            raise ValueError(f"weight must be unsigned (M,R^3), got {self.weight.dtype} {self.weight.shape}")

    @property
    def block_count(self) -> int:
        return len(self.keys)

    @cached_property
    def voxel_count(self) -> int:
        """Observed voxels (weight > 0)."""
        return int(np.count_nonzero(self.weight))

    def same_as(self, other: VoxelBlocks) -> bool:
        return all(
            a.dtype == b.dtype and np.array_equal(a, b)
            for a, b in ((self.keys, other.keys), (self.tsdf, other.tsdf), (self.weight, other.weight))
        )


def quantise(arrays: TsdfArrays, lattice: Lattice) -> VoxelBlocks:
    """The wire form of backend arrays; blocks with no observed voxel are dropped."""
    weight = arrays.weight
    observed = weight > 0
    keep = observed.any(axis=1)
    weight, observed = weight[keep], observed[keep]
    dtype = lattice.weight_dtype
    limit = np.iinfo(dtype).max
    units = np.rint(weight / lattice.weight_unit)
    units = np.clip(units, 1, limit) * observed  # an observed voxel never rounds down to "unseen"
    tsdf = np.clip(np.rint(arrays.tsdf[keep] * TSDF_SCALE), -TSDF_SCALE, TSDF_SCALE) * observed
    return VoxelBlocks(
        np.ascontiguousarray(arrays.keys[keep], dtype=np.int32), tsdf.astype(np.int8), units.astype(dtype)
    )


def pack_blocks(keys: np.ndarray, tsdf: np.ndarray, weight: np.ndarray) -> bytes:
    """Blocks as a patch's payload lays them out before compression: keys int16 (M,3), then which voxels are
    observed (M, ceil(R^3/8) bytes, numpy's packbits: big-endian bits per block row), then the observed voxels'
    tsdf int8, then their weights' low bytes and (uint16 weights) their high bytes. Only observed voxels carry
    values, and each byte of a weight in a plane of its own compresses better than interleaved."""
    observed = weight > 0
    weights = weight[observed]
    planes = [weights.astype(np.uint8)] if weights.dtype.itemsize == 1 else [weights & 0xFF, weights >> 8]
    parts = [keys.astype("<i2"), np.packbits(observed, axis=1), tsdf[observed].astype(np.int8)]
    return b"".join(part.tobytes() for part in parts + [plane.astype(np.uint8) for plane in planes])


def packed_size(lattice: Lattice, blocks: int, voxels: int) -> int:
    """Bytes of `pack_blocks` for this many blocks and observed voxels."""
    mask_bytes = -(-lattice.voxels_per_block // 8)
    return blocks * (3 * 2 + mask_bytes) + voxels * (1 + lattice.weight_dtype.itemsize)


def is_rigid(T: np.ndarray, tolerance: float = 1e-4) -> bool:
    """A finite 4x4 rigid transform (rotation part orthonormal with det +1, last row 0 0 0 1)."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        return False
    rot = T[:3, :3]
    return (
        np.allclose(T[3], (0.0, 0.0, 0.0, 1.0), atol=0.0)
        and np.allclose(rot @ rot.T, np.eye(3), atol=tolerance)
        and abs(float(np.linalg.det(rot)) - 1.0) < tolerance
    )


@dataclass(frozen=True, eq=False)
class Patch:
    """A sealed patch. `bounds` is the world box holding every block's voxel sample points."""

    id: PatchId
    lattice: Lattice
    span: FrameSpan
    anchor_pose: np.ndarray  # 4x4 camera-to-world of the first frame
    bounds: tuple[np.ndarray, np.ndarray]
    blocks: VoxelBlocks = field(repr=False)

    def __post_init__(self) -> None:
        if not is_rigid(self.anchor_pose):
            raise ValueError("anchor pose must be a finite rigid 4x4 transform")
        if self.blocks.tsdf.shape[1] != self.lattice.voxels_per_block:
            held, needed = self.blocks.tsdf.shape[1], self.lattice.voxels_per_block
            raise ValueError(f"blocks hold {held} voxels, the lattice {needed}")
        if self.blocks.weight.dtype != self.lattice.weight_dtype:
            raise ValueError(f"weights are {self.blocks.weight.dtype}, the lattice needs {self.lattice.weight_dtype}")
        if self.span.first > self.span.last or not self.span.t_first <= self.span.t_last:
            raise ValueError(f"bad frame span {self.span}")

    @classmethod
    def seal(
        cls, pid: PatchId, lattice: Lattice, span: FrameSpan, anchor_pose: np.ndarray, blocks: VoxelBlocks
    ) -> Patch:
        """A patch whose bounds are those of its blocks."""
        pose = np.array(anchor_pose, dtype=np.float64)
        return cls(pid, lattice, span, pose, lattice.block_bounds(blocks.keys), blocks)

    @property
    def voxel_count(self) -> int:
        return self.blocks.voxel_count

    @property
    def block_count(self) -> int:
        return self.blocks.block_count

    def __hash__(self) -> int:
        return hash(self.id)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Patch):
            return NotImplemented
        return (
            self.id == other.id
            and self.lattice == other.lattice
            and self.span == other.span
            and np.array_equal(self.anchor_pose, other.anchor_pose)
            and all(np.array_equal(a, b) for a, b in zip(self.bounds, other.bounds))
            and self.blocks.same_as(other.blocks)
        )
