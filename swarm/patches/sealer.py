"""The open patch: frames are integrated into a fresh TSDF until a trigger seals it into a `Patch`.

Triggers (checked after each frame): `patch_frames` frames integrated, or the camera travelled `patch_distance_m`
(path length from the patch's first frame). The open patch is never shared; `open_blocks` gives its quantised
snapshot so that the agent's own queries can include it.
"""

from __future__ import annotations

import numpy as np

from swarm.patches.backend import TsdfBackend
from swarm.patches.lattice import Lattice
from swarm.patches.patch import FrameSpan, Patch, PatchId, VoxelBlocks, quantise


class PatchSealer:
    def __init__(
        self,
        backend: TsdfBackend,
        producer: int,
        epoch: int,
        patch_frames: int = 15,
        patch_distance_m: float = 2.0,
        first_seq: int = 0,
    ) -> None:
        if patch_frames < 1 or patch_distance_m <= 0:
            raise ValueError("patch_frames must be >= 1 and patch_distance_m > 0")
        self.backend = backend
        self.lattice: Lattice = backend.lattice
        self.producer = producer
        self.epoch = epoch
        self.patch_frames = patch_frames
        self.patch_distance_m = patch_distance_m
        self.next_seq = first_seq
        self.frame_index = 0  # frames integrated since this sealer started
        self._open_frames = 0
        self._travelled = 0.0
        self._first: tuple[int, float, np.ndarray] | None = None  # index, time, pose of the open patch's first frame
        self._last: tuple[int, float, np.ndarray] | None = None

    @property
    def open_frames(self) -> int:
        return self._open_frames

    def add_frame(
        self, depth: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray, t: float, max_range: float
    ) -> Patch | None:
        """Integrate one frame into the open patch; return the sealed patch if this frame triggered a seal."""
        pose = np.array(T_world_cam, dtype=np.float64)
        if not np.all(np.isfinite(pose)) or not np.all(np.isfinite(K)):
            raise ValueError("camera pose and intrinsics must be finite")
        self.backend.integrate(depth, K, pose, max_range)
        if self._first is None:
            self._first = (self.frame_index, float(t), pose)
        else:
            assert self._last is not None  # set with _first
            self._travelled += float(np.linalg.norm(pose[:3, 3] - self._last[2][:3, 3]))
        self._last = (self.frame_index, float(t), pose)
        self.frame_index += 1
        self._open_frames += 1
        if self._open_frames >= self.patch_frames or self._travelled >= self.patch_distance_m:
            return self.seal()
        return None

    def seal(self) -> Patch | None:
        """Seal the open patch now; None (and nothing consumed) if it holds no frame or no observed voxel."""
        if self._first is None or self._last is None:
            return None
        blocks = quantise(self.backend.extract(), self.lattice)
        first, last = self._first, self._last
        self.backend.reset()
        self._first, self._last, self._open_frames, self._travelled = None, None, 0, 0.0
        if blocks.block_count == 0:
            return None
        pid = PatchId(self.producer, self.epoch, self.next_seq)
        self.next_seq += 1
        span = FrameSpan(first[0], last[0], first[1], last[1])
        return Patch.seal(pid, self.lattice, span, first[2], blocks)

    def open_blocks(self) -> VoxelBlocks | None:
        """The open patch in wire form (a copy), or None when no frame is open."""
        if self._first is None:
            return None
        return quantise(self.backend.extract(), self.lattice)
