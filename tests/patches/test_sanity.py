"""Patch sanity (issue 25): a patch no camera could have made (no observed voxel, far more blocks than one seal
window can hold, nothing in the mission volume) is refused on receipt, never fused, held or served; and the
sealer never seals what a receiver would refuse."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

import numpy as np
import pytest

from swarm.bus.counters import TrafficCounters
from swarm.bus.keys import Keys
from swarm.config import CameraSettings, MappingSettings, SwarmConfig, SyncSettings
from swarm.patches.backend import VoxelBlockGridBackend
from swarm.patches.carving import frame_blocks
from swarm.patches.lattice import Lattice
from swarm.patches.mapper import Mapper
from swarm.patches.patch import FrameSpan, Patch, PatchId, VoxelBlocks
from swarm.patches.sealer import PatchSealer, frame_block_bound, patch_block_limit
from swarm.patches.wire import PatchDecodeError, decode_patch, encode_patch
from swarm.sync.chunks import split_patch
from swarm.sync.requests import request_parameters
from swarm.sync.service import PatchSync
from tests.patches.scene import CENTRE, MAX_RANGE, ROOM_HI, ROOM_LO, intrinsics, pose, render_room, rotate_in_place

BOUNDS = (ROOM_LO - 1.0, ROOM_HI + 1.0)
MAX_BYTES = 4 << 20
LATTICE = Lattice.from_settings(MappingSettings())


def _reason(data: bytes, **limits: object) -> str | None:
    try:
        decode_patch(data, LATTICE, MAX_BYTES, **limits)  # type: ignore[arg-type]
    except PatchDecodeError as exc:
        return exc.reason
    return None


def _patch(keys: list[tuple[int, int, int]], observed: list[int]) -> Patch:
    """Blocks at `keys`, block i with `observed[i]` voxels seen (weight 1, tsdf 0.5)."""
    n = LATTICE.voxels_per_block
    weight = np.zeros((len(keys), n), dtype=LATTICE.weight_dtype)
    for i, count in enumerate(observed):
        weight[i, :count] = 1
    tsdf = (weight > 0).astype(np.int8) * 64
    blocks = VoxelBlocks(np.array(keys, dtype=np.int32).reshape(-1, 3), tsdf, weight)
    return Patch.seal(PatchId(3, 1, 0), LATTICE, FrameSpan(0, 0, 0.0, 0.0), np.eye(4), blocks)


def _room_patch(mapper: Mapper) -> Patch:
    """A real patch: the room seen from its centre, frames turning round (sealed by the frame trigger)."""
    for frame in rotate_in_place(yaws=5, pitches=(0.0,)):
        sealed = mapper.integrate(frame.depth, frame.K, frame.T, frame.t, MAX_RANGE)
    sealed = mapper.seal() if sealed is None else sealed
    assert sealed is not None
    return sealed


# --- on receipt ---------------------------------------------------------------------------------------------


def test_a_patch_with_no_observed_voxel_is_refused_as_empty() -> None:
    assert _reason(encode_patch(_patch([], []))) == "empty"
    assert _reason(encode_patch(_patch([(0, 0, 0)], [0]))) == "empty"  # a block, nothing seen in it
    assert _reason(encode_patch(_patch([(0, 0, 0)], [1]))) is None


def test_a_block_with_no_observed_voxel_is_refused_even_beside_observed_ones() -> None:
    assert _reason(encode_patch(_patch([(0, 0, 0), (1, 0, 0)], [5, 0]))) == "invalid"
    assert _reason(encode_patch(_patch([(0, 0, 0), (1, 0, 0)], [5, 1]))) is None


def test_more_blocks_than_the_limit_are_refused_before_decompression() -> None:
    data = encode_patch(_patch([(i, 0, 0) for i in range(10)], [1] * 10))
    assert _reason(data, max_blocks=9) == "too_many_blocks"
    assert _reason(data, max_blocks=10) is None
    assert _reason(data) is None  # no bound given: as before


def test_a_patch_with_no_block_in_the_mission_volume_is_refused() -> None:
    data = encode_patch(_patch([(0, 0, 0), (1, 0, 0)], [1, 1]))  # sample points: x 0 to 1.5, y and z 0 to 0.7
    assert _reason(data, volume=((10.0, 10.0, 10.0), (20.0, 20.0, 20.0))) == "outside_volume"
    assert _reason(data, volume=((1.5, -1.0, -1.0), (5.0, 5.0, 5.0))) is None  # touching is inside
    assert _reason(data, volume=((1.51, -1.0, -1.0), (5.0, 5.0, 5.0))) == "outside_volume"
    assert _reason(data, volume=((-1.0, 0.71, -1.0), (5.0, 5.0, 5.0))) == "outside_volume"
    assert _reason(data, volume=((-5.0, -5.0, -5.0), (0.4, 5.0, 5.0))) is None  # partly inside
    apart = encode_patch(_patch([(-3, 0, 0), (3, 0, 0)], [1, 1]))  # blocks on both sides of a volume between
    assert _reason(apart, volume=((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))) == "outside_volume"


def test_a_mapper_refuses_a_peer_patch_outside_its_volume_and_nothing_changes() -> None:
    peer = Mapper(MappingSettings(), producer=3, epoch=1, bounds=(BOUNDS[0] + 50.0, BOUNDS[1] + 50.0))
    T = pose(CENTRE + 50.0, 0.0)
    peer.integrate(render_room(intrinsics(), pose(CENTRE, 0.0)), intrinsics(), T, 0.0, MAX_RANGE)
    far = peer.seal()  # the room seen 50 m away: a frame transform gone wrong
    assert far is not None
    data = peer.data(far.id)
    assert data is not None

    ours = Mapper(MappingSettings(), producer=2, epoch=1, bounds=BOUNDS)
    with pytest.raises(PatchDecodeError) as refused:
        ours.receive_wire(data, far.id, MAX_BYTES)
    assert refused.value.reason == "outside_volume"
    assert not ours.holds(far.id) and far.id not in ours.fused and ours.fused.voxel_count == 0


def test_a_refused_patch_is_never_held_announced_or_served() -> None:
    peer = Mapper(MappingSettings(), producer=3, epoch=1, bounds=(BOUNDS[0] + 50.0, BOUNDS[1] + 50.0))
    good_peer = Mapper(MappingSettings(), producer=4, epoch=1, bounds=BOUNDS)
    peer.integrate(render_room(intrinsics(), pose(CENTRE, 0.0)), intrinsics(), pose(CENTRE + 50.0, 0.0), 0, 8.0)
    far, good = peer.seal(), _room_patch(good_peer)
    assert far is not None
    ours = Mapper(MappingSettings(), producer=2, epoch=1, bounds=BOUNDS)

    async def sink(data: bytes, pid: PatchId) -> None:
        ours.receive_wire(data, pid, MAX_BYTES)

    async def deliver() -> PatchSync:
        bus = SimpleNamespace(keys=Keys("sanity"), counters=TrafficCounters())
        sync = PatchSync(bus, SyncSettings(), 2, sink, lambda: (0.0, 0.0, 0.0), MAX_BYTES)  # type: ignore[arg-type]
        for source, patch in ((peer, far), (good_peer, good)):
            data = source.data(patch.id)
            assert data is not None
            for chunk in split_patch(patch.id.producer, patch.id, data, 8192):
                task = sync._take(chunk, via_pull=False)
                if task is not None:
                    await task
        return sync

    sync = asyncio.run(deliver())
    assert sync.held_ids() == [good.id] and sync.rejected == {"outside_volume": 1}
    assert sync.bus.counters.dropped_count("patch_chunk", "patch_outside_volume") == 1
    assert ours.held_ids() == [good.id]
    asked = dict(part.split("=") for part in request_parameters([far.id], 5).split(";"))
    assert sync._serve(sync.keys.store(2), asked) is None  # not served to whoever asks


# --- the sealer seals only what receivers accept -------------------------------------------------------------


def test_a_frame_that_sees_nothing_seals_no_patch_and_uses_no_sequence_number() -> None:
    sealer = PatchSealer(VoxelBlockGridBackend(LATTICE), 2, 1, patch_frames=1)
    nothing = np.zeros((120, 160), dtype=np.float32)  # no return anywhere: carves nothing
    assert sealer.add_frame(nothing, intrinsics(), pose(CENTRE, 0.0), 0.0, MAX_RANGE) is None
    assert sealer.next_seq == 0
    seen = sealer.add_frame(render_room(intrinsics(), pose(CENTRE, 0.0)), intrinsics(), pose(CENTRE, 0.0), 1, 8.0)
    assert seen is not None and seen.id.seq == 0 and seen.voxel_count > 0


def test_the_open_patch_is_sealed_at_half_the_block_limit() -> None:
    frames = rotate_in_place(yaws=8, pitches=(0.0,))
    one = VoxelBlockGridBackend(LATTICE)
    one.integrate(frames[0].depth, frames[0].K, frames[0].T, MAX_RANGE)
    limit = 2 * one.block_count + 2  # the first frame stays under half, the second takes it over
    sealer = PatchSealer(VoxelBlockGridBackend(LATTICE), 2, 1, patch_frames=100, max_blocks=limit)
    first = sealer.add_frame(frames[0].depth, frames[0].K, frames[0].T, frames[0].t, MAX_RANGE)
    second = sealer.add_frame(frames[1].depth, frames[1].K, frames[1].T, frames[1].t, MAX_RANGE)
    assert first is None and second is not None
    assert second.span.frames == 2 and second.block_count <= limit
    assert _reason(encode_patch(second), max_blocks=limit) is None


def test_a_patch_over_the_limit_or_outside_the_volume_is_not_sealed_and_is_counted() -> None:
    frame = rotate_in_place(yaws=1, pitches=(0.0,))[0]
    tight = PatchSealer(VoxelBlockGridBackend(LATTICE), 2, 1, patch_frames=100, max_blocks=3)
    assert tight.add_frame(frame.depth, frame.K, frame.T, 0.0, MAX_RANGE) is None  # sealed at half: refused
    assert tight.not_sealed == {"too_many_blocks": 1} and tight.next_seq == 0 and tight.open_frames == 0

    away = PatchSealer(VoxelBlockGridBackend(LATTICE), 2, 1, patch_frames=1, volume=(BOUNDS[0] + 50, BOUNDS[1] + 50))
    assert away.add_frame(frame.depth, frame.K, frame.T, 0.0, MAX_RANGE) is None
    assert away.not_sealed == {"outside_volume": 1} and away.next_seq == 0


# --- the default bound -------------------------------------------------------------------------------------


def test_one_frame_touches_no_more_blocks_than_the_bound_even_seeing_everything_at_max_range() -> None:
    camera = CameraSettings()
    K = intrinsics(camera.width, camera.height, camera.hfov_deg)
    far = np.full((camera.height, camera.width), camera.max_range_m, dtype=np.float32)  # the largest frustum
    for pitch in (0.0, 30.0, 45.0):  # axis-aligned and oblique: the block grid is the world's
        touched = len(frame_blocks(far, K, LATTICE.to_lattice_frame(pose(CENTRE, 17.0, pitch)), LATTICE, 8.0))
        assert 0 < touched <= frame_block_bound(LATTICE, camera)
    assert frame_block_bound(LATTICE, camera) == 8613  # the figure docs/security.md gives


def test_the_default_limit_is_far_above_a_real_patch_and_follows_the_settings() -> None:
    config = SwarmConfig()
    limit = patch_block_limit(config.mapping, config.camera)
    assert limit == 2 * 8613
    real = _room_patch(Mapper(config.mapping, producer=2, epoch=1, bounds=BOUNDS, max_blocks=limit))
    assert real.block_count * 5 < limit
    finer = config.mapping.model_copy(update={"voxel_size_m": 0.05})  # blocks of 0.4 m and a thinner band
    assert 4 < patch_block_limit(finer, config.camera) / limit < 8
    assert patch_block_limit(config.mapping.model_copy(update={"max_patch_blocks": 500}), config.camera) == 500
