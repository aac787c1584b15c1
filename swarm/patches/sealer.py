"""The open patch: frames are integrated into a fresh TSDF until a trigger seals it into a `Patch`.

Triggers (checked after each frame): `patch_frames` frames integrated, or the camera travelled `patch_distance_m`
(path length from the patch's first frame), or the open patch holds half of `max_blocks` blocks. The open patch is
never shared; `open_blocks` gives its quantised snapshot so that the agent's own queries can include it.

Stretch (`stretch` > 1, with a `novelty` function): at the frame or distance trigger, an open patch of which less
than `novel_fraction` of the blocks are new to the map (`novelty(keys)`) is not sealed yet, but goes on until
`stretch` times either trigger (or half the block bound). A drone turning at a viewpoint or flying back through
mapped space then sends one patch where it sent `stretch`; what it sees for the first time still goes out at
the normal triggers (past the trigger the share is checked again every NOVELTY_RECHECK_FRAMES frames). Every
observation is kept (the patch integrates them all), so the map is the same; only when the others get the
re-observations changes. Replaying the office 5-drone mission's patches, most of them brought no block new to
the union of the earlier ones, and merging up to 4 when under 30 % new cut their bytes from 10.6 to 6.4 times
the final map.

Changes only (with a `share` function, `mapping.patch_changes_only`): at the seal, the patch keeps only what
`share` returns: the voxels the drone's map has to change, with every observation of them not shared before
(`swarm.patches.unshared`). A patch left with no voxel is not sealed (and consumes no sequence number).

What the sealer seals, every receiver accepts (`swarm.patches.wire`): a patch with no observed voxel is not sealed
(and consumes no sequence number), nor is one with more than `max_blocks` blocks or none in the mission `volume`
(counted in `not_sealed` by the receiver's reason: a patch peers would refuse would otherwise be announced, asked
for and refused again and again).

The block bound (`patch_block_limit`): one frame touches only blocks within a block diagonal of the camera's
frustum out to max range plus the truncation distance, widened by the truncation band around each measured point
(`swarm.patches.carving`); those blocks are disjoint, so there are at most as many as fit in the frustum's bounding
box widened that much. The limit is twice that, and the sealer seals once the open patch holds half the limit, so
the frame that crosses half cannot take a patch past it. With the defaults (160x120 px, 90 degrees, 8 m, 0.1 m
voxels, 8^3 blocks) one frame can touch at most 8,613 blocks, and the limit is 17,226 blocks (26.6 MB before
compression with uint16 weights, under the decoder's 64 MiB for 4 MiB patches); a real 15-frame patch at 0.1 m
touches 1-2 k blocks. It assumes the camera is what `camera` says, as the exploration's view model does.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from swarm.config import CameraSettings, MappingSettings
from swarm.patches.backend import TsdfBackend
from swarm.patches.fused import Bounds
from swarm.patches.lattice import Lattice
from swarm.patches.patch import FrameSpan, Patch, PatchId, VoxelBlocks, quantise
from swarm.patches.wire import outside_volume

NOVELTY_RECHECK_FRAMES = 3  # a deferred seal re-checks what is new every this many frames (0.3 s at 10 Hz)


def frame_block_bound(lattice: Lattice, camera: CameraSettings) -> int:
    """The most blocks one frame of `camera` can touch on `lattice` (module doc)."""
    tan_h = math.tan(math.radians(camera.hfov_deg) / 2)
    tan_v = tan_h * camera.height / camera.width  # square pixels, as the simulated camera and the view model
    reach = camera.max_range_m + lattice.truncation_m
    widen = math.sqrt(3) * (lattice.truncation_m + lattice.block_size)
    volume = (2 * reach * tan_h + 2 * widen) * (2 * reach * tan_v + 2 * widen) * (reach + 2 * widen)
    return math.ceil(volume / lattice.block_size**3)


def patch_block_limit(mapping: MappingSettings, camera: CameraSettings) -> int:
    """The most blocks a patch may have: `mapping.max_patch_blocks`, or twice what one frame can touch."""
    if mapping.max_patch_blocks is not None:
        return mapping.max_patch_blocks
    return 2 * frame_block_bound(Lattice.from_settings(mapping), camera)


class PatchSealer:
    def __init__(
        self,
        backend: TsdfBackend,
        producer: int,
        epoch: int,
        patch_frames: int = 15,
        patch_distance_m: float = 2.0,
        first_seq: int = 0,
        max_blocks: int | None = None,
        volume: Bounds | None = None,
        stretch: int = 1,
        novelty: Callable[[np.ndarray], float] | None = None,
        novel_fraction: float = 0.2,
        share: Callable[[VoxelBlocks], VoxelBlocks] | None = None,
    ) -> None:
        if patch_frames < 1 or patch_distance_m <= 0 or stretch < 1:
            raise ValueError("patch_frames and stretch must be >= 1 and patch_distance_m > 0")
        self.stretch = stretch if novelty is not None else 1
        self.novelty = novelty  # the share of (N,3) block keys the map does not hold yet
        self.novel_fraction = novel_fraction
        self.stretched = 0  # frames at which a due seal was put off because the open patch had little new
        self.share = share  # what of a sealed patch's blocks goes out (changes only: swarm.patches.unshared)
        self.nothing_to_share = 0  # open patches not sealed because `share` kept none of their voxels
        self.backend = backend
        self.lattice: Lattice = backend.lattice
        self.producer = producer
        self.epoch = epoch
        self.patch_frames = patch_frames
        self.patch_distance_m = patch_distance_m
        self.next_seq = first_seq
        self.max_blocks = max_blocks
        self.volume = volume
        self.not_sealed: dict[str, int] = {}  # open patches dropped because a receiver would refuse them, by reason
        self.frame_index = 0  # frames integrated since this sealer started
        self._open_frames = 0
        self._frames_past_due = 0  # frames of the open patch since its trigger was due (stretched patches only)
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
        if self.max_blocks is not None and 2 * self.backend.block_count >= self.max_blocks:
            return self.seal()
        # how far the open patch is along each trigger: 1 is due, `stretch` is as long as it may go on
        frames, travelled = self._open_frames / self.patch_frames, self._travelled / self.patch_distance_m
        if frames >= self.stretch or travelled >= self.stretch:
            return self.seal()
        due = frames >= 1 or travelled >= 1
        if due and self.stretch > 1:
            self._frames_past_due += 1
            # Checked at the trigger and then every NOVELTY_RECHECK_FRAMES frames: new space seen meanwhile is
            # sealed within that many frames. A check scans every block of the open patch and its slots in the map
            # (3-6 ms a frame for the few thousand blocks of a stretched patch in a large hall).
            if (self._frames_past_due - 1) % NOVELTY_RECHECK_FRAMES or self._has_little_new():
                self.stretched += 1
                return None
        return self.seal() if due else None

    def _has_little_new(self) -> bool:
        assert self.novelty is not None  # stretch > 1 only with a novelty function
        return self.novelty(self.backend.keys()) < self.novel_fraction

    def seal(self) -> Patch | None:
        """Seal the open patch now; None (and nothing consumed) if it holds no frame or no observed voxel, or if a
        receiver would refuse it (more than `max_blocks` blocks, none in `volume`: counted in `not_sealed`)."""
        if self._first is None or self._last is None:
            return None
        blocks = quantise(self.backend.extract(), self.lattice)
        first, last = self._first, self._last
        self.backend.reset()
        self._first, self._last, self._open_frames, self._travelled = None, None, 0, 0.0
        self._frames_past_due = 0
        if blocks.block_count == 0:  # quantise keeps only blocks with an observed voxel: none observed
            return None
        if self.share is not None:
            blocks = self.share(blocks)
            if blocks.block_count == 0:
                self.nothing_to_share += 1
                return None
        refused = self._refused(blocks)
        if refused is not None:
            self.not_sealed[refused] = self.not_sealed.get(refused, 0) + 1
            return None
        pid = PatchId(self.producer, self.epoch, self.next_seq)
        self.next_seq += 1
        span = FrameSpan(first[0], last[0], first[1], last[1])
        return Patch.seal(pid, self.lattice, span, first[2], blocks)

    def _refused(self, blocks: VoxelBlocks) -> str | None:
        """The reason a receiver would refuse these blocks (`swarm.patches.wire`), or None."""
        if self.max_blocks is not None and blocks.block_count > self.max_blocks:
            return "too_many_blocks"
        if self.volume is not None and outside_volume(self.lattice, blocks.keys, self.volume):
            return "outside_volume"
        return None

    def open_blocks(self) -> VoxelBlocks | None:
        """The open patch in wire form (a copy), or None when no frame is open."""
        if self._first is None:
            return None
        return quantise(self.backend.extract(), self.lattice)
