"""The shared voxel lattice: mission constants every agent must agree on, and the one place that maps
points, voxel indices and block keys.

Conventions are Open3D's `VoxelBlockGrid` ones, so its arrays can be used without conversion:

- voxel index i (int, 3 axes) has its sample point at ``origin + i * voxel_size`` (a lattice point, not a cell
  centre); a point belongs to the voxel whose sample point is nearest (``round``);
- block key k holds voxels ``k * R + (x, y, z)`` for x, y, z in [0, R); inside a block the R^3 values are stored
  in ``[z, y, x]`` order (x fastest), i.e. flat index ``(z * R + y) * R + x``;
- tsdf is the truncated signed distance divided by the truncation distance, in [-1, 1], positive in front of
  the surface.

The weight law is part of the lattice because it fixes what a weight means (and how it is quantised on the
wire): "constant" adds 1 per observation (wire unit 1, uint8); "inverse_square" adds (1 m / z)^2 with z the
distance from the sensor to the voxel (wire unit 1/256, uint16); "dropoff" adds 1 in front of the surface and
down to one voxel behind it, then less, linearly, down to 0 at the truncation distance (voxblox's drop-off;
wire unit 1/16, uint16).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import get_args

import numpy as np
import numpy.typing as npt

from swarm.config import MappingSettings, Vec3, WeightLaw

WEIGHT_LAWS: tuple[str, ...] = get_args(WeightLaw)

_WEIGHT_UNIT = {"constant": 1.0, "inverse_square": 1.0 / 256.0, "dropoff": 1.0 / 16.0}
_WEIGHT_DTYPE: dict[str, np.dtype[np.uint8 | np.uint16]] = {
    "constant": np.dtype(np.uint8),
    "inverse_square": np.dtype(np.uint16),
    "dropoff": np.dtype(np.uint16),
}


@dataclass(frozen=True)
class Lattice:
    voxel_size: float = 0.1
    block_resolution: int = 8
    truncation_voxels: float = 4.0
    origin: Vec3 = (0.0, 0.0, 0.0)
    weight_law: WeightLaw = "constant"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.voxel_size) and self.voxel_size > 0):
            raise ValueError(f"voxel size must be positive, got {self.voxel_size}")
        if not 2 <= self.block_resolution <= 64:
            raise ValueError(f"block resolution must be in 2..64, got {self.block_resolution}")
        if not (math.isfinite(self.truncation_voxels) and self.truncation_voxels > 0):
            raise ValueError(f"truncation must be positive, got {self.truncation_voxels}")
        if len(self.origin) != 3 or not all(math.isfinite(c) for c in self.origin):
            raise ValueError(f"origin must be 3 finite numbers, got {self.origin}")
        if self.weight_law not in WEIGHT_LAWS:
            raise ValueError(f"weight law must be one of {WEIGHT_LAWS}, got {self.weight_law!r}")
        object.__setattr__(self, "origin", tuple(float(c) for c in self.origin))

    @classmethod
    def from_settings(cls, settings: MappingSettings, origin: Vec3 = (0.0, 0.0, 0.0)) -> Lattice:
        return cls(
            voxel_size=settings.voxel_size_m,
            block_resolution=settings.block_resolution,
            truncation_voxels=settings.truncation_voxels,
            origin=origin,
            weight_law=settings.weight_law,
        )

    # --- derived constants -----------------------------------------------------------------------------------

    @property
    def block_size(self) -> float:
        return self.voxel_size * self.block_resolution

    @property
    def truncation_m(self) -> float:
        return self.voxel_size * self.truncation_voxels

    @property
    def voxels_per_block(self) -> int:
        return self.block_resolution**3

    @property
    def weight_unit(self) -> float:
        """The weight of one unit of a quantised (wire and fused-map) weight."""
        return _WEIGHT_UNIT[self.weight_law]

    @property
    def weight_dtype(self) -> np.dtype[np.uint8 | np.uint16]:
        """The dtype of quantised weights on the wire."""
        return _WEIGHT_DTYPE[self.weight_law]

    @property
    def origin_array(self) -> npt.NDArray[np.float64]:
        return np.array(self.origin, dtype=np.float64)

    def weight_units(self, weight: float) -> int:
        """The smallest number of weight units that reaches `weight` (a known-threshold in units)."""
        return max(1, math.ceil(weight / self.weight_unit - 1e-9))

    # --- mappings --------------------------------------------------------------------------------------------

    def point_to_voxel(self, points: np.ndarray) -> np.ndarray:
        """(N,3) world points -> (N,3) int64 index of the voxel whose sample point is nearest."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return np.rint((p - self.origin_array) / self.voxel_size).astype(np.int64)

    def voxel_to_point(self, index: np.ndarray) -> np.ndarray:
        """(N,3) voxel indices -> (N,3) world sample points."""
        return np.asarray(index, dtype=np.float64).reshape(-1, 3) * self.voxel_size + self.origin_array

    def voxel_to_block(self, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,3) voxel indices -> ((N,3) int64 block keys, (N,) int64 flat index inside the block)."""
        i = np.asarray(index, dtype=np.int64).reshape(-1, 3)
        r = self.block_resolution
        keys = np.floor_divide(i, r)
        local = i - keys * r
        return keys, (local[:, 2] * r + local[:, 1]) * r + local[:, 0]

    def point_to_block(self, points: np.ndarray) -> np.ndarray:
        """(N,3) world points -> (N,3) int64 key of the block whose cell [k*B, (k+1)*B) holds the point."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return np.floor((p - self.origin_array) / self.block_size).astype(np.int64)

    def local_offsets(self) -> npt.NDArray[np.int64]:
        """(R^3, 3) int64 (x, y, z) offsets of a block's voxels, in storage order."""
        r = np.arange(self.block_resolution)
        z, y, x = np.meshgrid(r, r, r, indexing="ij")
        return np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)

    def block_voxel_indices(self, keys: np.ndarray) -> np.ndarray:
        """(M,3) block keys -> (M, R^3, 3) int64 voxel indices in storage order."""
        k = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
        return k[:, None, :] * self.block_resolution + self.local_offsets()[None, :, :]

    def block_bounds(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World box (lo, hi) spanned by the sample points of the given blocks (empty -> origin, origin)."""
        k = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
        if len(k) == 0:
            return self.origin_array.copy(), self.origin_array.copy()
        r = self.block_resolution
        lo = self.voxel_to_point(k.min(axis=0) * r)[0]
        hi = self.voxel_to_point(k.max(axis=0) * r + (r - 1))[0]
        return lo, hi

    def to_lattice_frame(self, T_world_cam: np.ndarray) -> np.ndarray:
        """The camera pose with the lattice origin subtracted (what Open3D, which has no origin, expects)."""
        T = np.array(T_world_cam, dtype=np.float64).reshape(4, 4)
        T[:3, 3] -= self.origin_array
        return T

    def describe(self) -> str:
        return (
            f"voxel {self.voxel_size:g} m, block {self.block_resolution}^3, truncation {self.truncation_voxels:g} "
            f"voxels, origin {self.origin}, weights {self.weight_law}"
        )
