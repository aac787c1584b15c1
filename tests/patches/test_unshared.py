"""Changes only: which voxels a sealed patch shares, and what is held back until it says something new."""

import numpy as np

from swarm.patches.fused import FREE, OCCUPIED, FusedMap
from swarm.patches.lattice import Lattice
from swarm.patches.patch import FrameSpan, Patch, PatchId, VoxelBlocks
from swarm.patches.unshared import UnsharedObservations

LATTICE = Lattice(0.1, 4, 4.0, weight_law="dropoff")  # known at 16 units (weight 1)
BOUNDS = ((0.0, 0.0, 0.0), (2.0, 2.0, 2.0))
KEY = np.array([[1, 1, 1]], dtype=np.int32)
V = LATTICE.voxels_per_block


def blocks(voxels: dict[int, tuple[int, int]], keys: np.ndarray = KEY) -> VoxelBlocks:
    """One block per key, each with these voxels: index -> (tsdf, weight units)."""
    tsdf = np.zeros((len(keys), V), dtype=np.int8)
    weight = np.zeros((len(keys), V), dtype=np.uint16)
    for index, (q, w) in voxels.items():
        tsdf[:, index], weight[:, index] = q, w
    return VoxelBlocks(keys, tsdf, weight)


def fused_with(voxels: dict[int, tuple[int, int]]) -> FusedMap:
    fused = FusedMap(LATTICE, BOUNDS)
    patch = Patch.seal(PatchId(9, 0, 0), LATTICE, FrameSpan(0, 0, 0.0, 0.0), np.eye(4), blocks(voxels))
    fused.add(patch)
    return fused


def shared(out: VoxelBlocks) -> dict[int, tuple[int, int]]:
    assert out.block_count <= 1
    if not out.block_count:
        return {}
    return {int(i): (int(out.tsdf[0, i]), int(out.weight[0, i])) for i in np.flatnonzero(out.weight[0])}


def test_only_voxels_the_map_does_not_know_or_whose_state_would_change_are_shared() -> None:
    # 0 free, 1 occupied, 2 observed but not known (unknown), 3 to 5 never observed
    fused = fused_with({0: (100, 16), 1: (-100, 16), 2: (50, 4)})
    unshared = UnsharedObservations(LATTICE, BOUNDS)
    seen = {0: (90, 16), 1: (50, 8), 2: (60, 4), 3: (-20, 2), 4: (90, 8), 5: (-127, 16)}
    out = unshared.share(blocks(seen), fused)
    # Held back: 0 stays free, 1 occupied (-1600 + 400 < 0). Shared: 2 is not known yet, 3 to 5 are new.
    assert shared(out) == {2: (60, 4), 3: (-20, 2), 4: (90, 8), 5: (-127, 16)}
    assert unshared.held_back == 2
    assert np.array_equal(out.keys, KEY)


def test_held_back_evidence_goes_out_whole_once_it_outweighs_the_map() -> None:
    fused = fused_with({1: (-100, 16)})  # occupied
    unshared = UnsharedObservations(LATTICE, BOUNDS)
    assert unshared.share(blocks({1: (50, 8)}), fused).block_count == 0  # -1600 + 400: still occupied
    out = unshared.share(blocks({1: (40, 32)}), fused)  # -1600 + 400 + 1280 > 0: the voxel is free now
    # both observations as one: weight 40, mean tsdf (8 * 50 + 32 * 40) / 40 = 42
    assert shared(out) == {1: (42, 40)}
    fused.add(Patch.seal(PatchId(1, 0, 0), LATTICE, FrameSpan(0, 1, 0.0, 0.1), np.eye(4), out))
    assert fused.state_at(LATTICE.origin_array + 0.1 * np.array([[5, 4, 4]])).tolist() == [FREE]
    # what went out is forgotten here: a third, agreeing look has nothing to add
    assert unshared.share(blocks({1: (60, 4)}), fused).block_count == 0


def test_noise_about_the_surface_stays_held_back() -> None:
    fused = fused_with({7: (-10, 64)})  # occupied, just behind the surface, seen a lot
    unshared = UnsharedObservations(LATTICE, BOUNDS)
    for q in (8, -12, 5, -3, 9, -6):  # flickers around it: never enough to move it across
        assert unshared.share(blocks({7: (q, 16)}), fused).block_count == 0
    assert unshared.held_back == 6


def test_blocks_outside_the_volume_are_left_out() -> None:
    keys = np.array([[1, 1, 1], [40, 40, 40]], dtype=np.int32)
    out = UnsharedObservations(LATTICE, BOUNDS).share(blocks({0: (100, 16)}, keys), FusedMap(LATTICE, BOUNDS))
    assert np.array_equal(out.keys, KEY) and shared(out) == {0: (100, 16)}


def test_a_shared_weight_is_capped_at_the_wires_largest_and_keeps_its_mean() -> None:
    fused = fused_with({0: (-127, 65535)})  # occupied, as heavily as one patch can say it
    unshared = UnsharedObservations(LATTICE, BOUNDS)
    assert unshared.share(blocks({0: (100, 60000)}), fused).block_count == 0
    out = unshared.share(blocks({0: (100, 60000)}), fused)  # 120000 units of free: more than the map's
    assert shared(out) == {0: (100, 65535)}


def test_evidence_held_back_answers_a_peer_that_contradicts_it() -> None:
    fused = fused_with({0: (127, 16)})  # free, known
    unshared = UnsharedObservations(LATTICE, BOUNDS)
    assert unshared.share(blocks({0: (127, 64)}), fused).block_count == 0  # agrees: held back
    peer = Patch.seal(PatchId(2, 0, 0), LATTICE, FrameSpan(0, 0, 0.0, 0.0), np.eye(4), blocks({0: (-100, 32)}))
    fused.add(peer)  # 16 * 127 - 32 * 100 < 0: the peer says occupied
    voxel = LATTICE.origin_array + 0.1 * np.array([[4, 4, 4]])
    assert fused.state_at(voxel).tolist() == [OCCUPIED]
    unshared.recheck(peer.blocks.keys, fused)
    elsewhere = np.array([[2, 1, 1]], dtype=np.int32)
    out = unshared.share(blocks({3: (127, 16)}, elsewhere), fused)  # the next seal, looking somewhere else
    assert out.keys.tolist() == [[2, 1, 1], [1, 1, 1]]  # its own blocks, then the contested one
    assert int(out.weight[1, 0]) == 64 and int(out.tsdf[1, 0]) == 127 and np.count_nonzero(out.weight[1]) == 1
    fused.add(Patch.seal(PatchId(1, 0, 0), LATTICE, FrameSpan(0, 1, 0.0, 0.1), np.eye(4), out))
    assert fused.state_at(voxel).tolist() == [FREE]  # 16 * 127 - 3200 + 64 * 127 > 0: the evidence of both
    unshared.recheck(peer.blocks.keys, fused)  # nothing held about it any more: nothing contested
    assert unshared.share(blocks({3: (127, 4)}, elsewhere), fused).block_count == 0


def test_contested_blocks_beyond_a_patchs_room_wait_for_the_next() -> None:
    keys = np.array([[1, 1, k] for k in range(4)], dtype=np.int32)
    fused = FusedMap(LATTICE, BOUNDS)
    fused.add(Patch.seal(PatchId(9, 0, 0), LATTICE, FrameSpan(0, 0, 0.0, 0.0), np.eye(4), blocks({0: (127, 16)}, keys)))
    unshared = UnsharedObservations(LATTICE, BOUNDS, max_blocks=2)
    assert unshared.share(blocks({0: (127, 64)}, keys), fused).block_count == 0  # all four agree: held back
    peer = Patch.seal(PatchId(2, 0, 0), LATTICE, FrameSpan(0, 0, 0.0, 0.0), np.eye(4), blocks({0: (-127, 32)}, keys))
    fused.add(peer)
    unshared.recheck(peer.blocks.keys, fused)  # four blocks contested
    elsewhere = np.array([[3, 3, 3]], dtype=np.int32)
    first = unshared.share(blocks({0: (127, 16)}, elsewhere), fused)
    second = unshared.share(blocks({1: (127, 16)}, elsewhere), fused)
    third = unshared.share(blocks({2: (127, 16)}, elsewhere), fused)
    assert [out.block_count for out in (first, second, third)] == [2, 2, 2]  # its own block and one contested
    contested = [tuple(k) for out in (first, second, third) for k in out.keys.tolist()[1:]]
    assert sorted(contested) == [(1, 1, 0), (1, 1, 1), (1, 1, 2)]  # the fourth waits for the next seal
