"""Sealing triggers, patch ids, the stores."""

import numpy as np
import pytest

from swarm.config import MappingSettings
from swarm.patches.mapper import Mapper
from swarm.patches.patch import PatchId
from swarm.patches.wire import decode_patch, encode_patch
from tests.patches.scene import CENTRE, MAX_RANGE, ROOM_HI, ROOM_LO, intrinsics, pose, render_room, rotate_in_place

BOUNDS = (ROOM_LO - 1.0, ROOM_HI + 1.0)


def test_patch_id_order_text_and_hash() -> None:
    ids = [PatchId(3, 1795340000000, 12), PatchId(1, 5, 0), PatchId(3, 1795340000000, 2), PatchId(3, 2, 40)]
    assert sorted(ids) == [ids[1], ids[3], ids[2], ids[0]]
    assert str(ids[0]) == "3.1795340000000.12"
    assert PatchId.parse("3.1795340000000.12") == ids[0]
    assert len({PatchId(1, 2, 3), PatchId(1, 2, 3)}) == 1
    for bad in ("1.2", "a.b.c", "1.2.-3"):
        with pytest.raises(ValueError):
            PatchId.parse(bad)
    with pytest.raises(ValueError):
        PatchId(-1, 0, 0)


def test_k_frames_seal_a_patch_and_the_open_patch_stays_private() -> None:
    mapper = Mapper(MappingSettings(patch_frames=5, patch_distance_m=100.0), producer=4, epoch=9, bounds=BOUNDS)
    frames = rotate_in_place()[:12]
    sealed = []
    for i, f in enumerate(frames):
        patch = mapper.integrate(f.depth, f.K, f.T, f.t, MAX_RANGE)
        assert (patch is not None) == (i in (4, 9))
        if patch:
            sealed.append(patch)
    assert [p.id for p in sealed] == [PatchId(4, 9, 0), PatchId(4, 9, 1)]
    first, second = sealed
    assert (first.span.first, first.span.last, first.span.frames) == (0, 4, 5)
    assert (second.span.first, second.span.last) == (5, 9)
    assert first.span.t_first == frames[0].t and first.span.t_last == frames[4].t
    assert np.array_equal(first.anchor_pose, frames[0].T) and np.array_equal(second.anchor_pose, frames[5].T)
    assert first.voxel_count > 0 and first.block_count > 0
    lo, hi = first.bounds
    assert np.all(lo <= CENTRE) and np.all(hi >= CENTRE)
    # two frames are open: they are in no store and in no fused patch id
    assert mapper.sealer.open_frames == 2
    assert mapper.held_ids() == [PatchId(4, 9, 0), PatchId(4, 9, 1)]
    assert mapper.private.ids() == mapper.held_ids() and len(mapper.public) == 0
    assert mapper.fused.ids == frozenset(mapper.held_ids())
    last = mapper.seal()
    assert last.id == PatchId(4, 9, 2) and last.span.frames == 2
    assert mapper.seal() is None  # nothing open


def test_distance_travelled_seals_a_patch() -> None:
    mapper = Mapper(MappingSettings(patch_frames=50, patch_distance_m=1.0), producer=1, epoch=0, bounds=BOUNDS)
    K = intrinsics()
    sealed_at = []
    for i in range(8):
        T = pose(CENTRE + [-1.4 + 0.4 * i, 0.0, 0.0], 90.0)
        if mapper.integrate(render_room(K, T), K, T, float(i), MAX_RANGE):
            sealed_at.append(i)
    # 0.4 m per frame: 1.2 m travelled at the 4th frame of each patch
    assert sealed_at == [3, 7]


def test_received_patches_are_stored_once_and_own_ones_are_not_stored_again() -> None:
    settings = MappingSettings(patch_frames=3, patch_stretch=1)
    a = Mapper(settings, producer=1, epoch=1, bounds=BOUNDS)
    b = Mapper(settings, producer=2, epoch=1, bounds=BOUNDS)
    patches = [p for f in rotate_in_place()[:9] if (p := a.integrate(f.depth, f.K, f.T, f.t, MAX_RANGE))]
    assert len(patches) == 3
    for p in patches:
        assert b.receive(p)
    digest = b.fused.digest()
    assert not b.receive(patches[1])
    assert b.fused.digest() == digest == a.fused.digest()
    assert b.public.ids() == [p.id for p in patches] and len(b.private) == 0
    assert not a.receive(patches[0])  # its own
    assert len(a.public) == 0
    assert b.get(patches[2].id) == patches[2] and b.holds(patches[0].id)
    assert b.data(patches[2].id) == a.data(patches[2].id) == encode_patch(patches[2])
    assert b.public.nbytes == sum(len(encode_patch(p)) for p in patches)


def test_a_received_patch_keeps_the_bytes_it_came_in() -> None:
    settings = MappingSettings(patch_frames=2)
    a = Mapper(settings, producer=1, epoch=1, bounds=BOUNDS)
    b = Mapper(settings, producer=2, epoch=1, bounds=BOUNDS)
    patch = [p for f in rotate_in_place()[:2] if (p := a.integrate(f.depth, f.K, f.T, f.t, MAX_RANGE))][0]
    data = a.data(patch.id)
    assert b.receive(decode_patch(data, b.lattice, settings.max_patch_bytes), data)
    assert b.data(patch.id) == data and b.public.info(patch.id).voxel_count == patch.voxel_count


def _looking_at_one_wall(n: int) -> list:
    """n frames from one spot, turning a little each way: after the first few, nothing new is seen."""
    K = intrinsics()
    from tests.patches.scene import Frame

    return [
        Frame(render_room(K, pose(CENTRE, 10.0 * (i % 2), 0.0)), K, pose(CENTRE, 10.0 * (i % 2), 0.0), 0.1 * i)
        for i in range(n)
    ]


def test_a_patch_with_little_new_goes_on_to_the_stretched_trigger_and_keeps_every_frame() -> None:
    frames = _looking_at_one_wall(40)
    plain, stretched = (  # each patch sealed whole: only the stretch differs
        Mapper(
            MappingSettings(patch_frames=5, patch_distance_m=100.0, patch_stretch=k, patch_changes_only=False),
            1,
            0,
            BOUNDS,
        )
        for k in (1, 3)
    )
    spans = {}
    for name, mapper in (("plain", plain), ("stretched", stretched)):
        sealed = [p for f in frames if (p := mapper.integrate(f.depth, f.K, f.T, f.t, MAX_RANGE)) is not None]
        spans[name] = [p.span.frames for p in sealed]
        mapper.seal()
    assert spans["plain"] == [5] * 8
    # the first patch is all new; after it the same wall again: 15 frames a patch, none of them left out
    assert spans["stretched"] == [5, 15, 15] and stretched.sealer.stretched > 0 and plain.sealer.stretched == 0
    assert stretched.fused.voxel_count == plain.fused.voxel_count  # the same voxels observed: only fewer patches


def test_a_patch_that_sees_new_space_is_sealed_at_the_normal_trigger() -> None:
    mapper = Mapper(MappingSettings(patch_frames=5, patch_distance_m=100.0, patch_stretch=3), 1, 0, BOUNDS)
    frames = rotate_in_place(yaws=8, pitches=(0.0,))  # a turn: each 5 frames look somewhere else
    sealed = [p for f in frames if (p := mapper.integrate(f.depth, f.K, f.T, f.t, MAX_RANGE)) is not None]
    assert sealed and sealed[0].span.frames == 5
    assert mapper.fused.novelty(sealed[0].blocks.keys) == 0.0  # what is sealed is in the map


def test_a_deferred_seal_checks_what_is_new_at_the_trigger_then_every_few_frames() -> None:
    from swarm.patches.backend import VoxelBlockGridBackend
    from swarm.patches.lattice import Lattice
    from swarm.patches.sealer import NOVELTY_RECHECK_FRAMES, PatchSealer

    checked_at: list[int] = []
    new_from = 9  # the open patch's frames from this one on see new space

    def novelty(keys: np.ndarray) -> float:
        checked_at.append(sealer.open_frames)
        return 1.0 if sealer.open_frames >= new_from else 0.0

    backend = VoxelBlockGridBackend(Lattice.from_settings(MappingSettings()))
    sealer = PatchSealer(backend, 1, 0, patch_frames=5, patch_distance_m=100.0, stretch=3, novelty=novelty)
    sealed_at = [
        f.t for f in _looking_at_one_wall(20) if sealer.add_frame(f.depth, f.K, f.T, f.t, MAX_RANGE) is not None
    ]
    step = NOVELTY_RECHECK_FRAMES
    assert checked_at[:2] == [5, 5 + step]  # at the trigger, then every `step` frames, not at every frame
    first_new_check = next(n for n in checked_at if n >= new_from)
    assert first_new_check < new_from + step and sealed_at[0] == pytest.approx(0.1 * (first_new_check - 1))
