"""Fusion: patches fused equal one TSDF integrated from the same frames; order, duplicates and the open patch
do not change the result."""

import random

import numpy as np
import pytest

from swarm.config import MappingSettings
from swarm.patches.backend import VoxelBlockGridBackend
from swarm.patches.fused import FREE, OCCUPIED, FusedMap
from swarm.patches.lattice import Lattice
from swarm.patches.mapper import Mapper
from swarm.patches.patch import TSDF_SCALE, Patch
from tests.patches.scene import CENTRE, MAX_RANGE, ROOM_HI, ROOM_LO, intrinsics, pose, render_room, rotate_in_place

BOUNDS = (ROOM_LO - 2.0, ROOM_HI + 2.0)


def flight():
    """Rotate in place, then a short translation (patches then overlap in varied ways)."""
    frames = rotate_in_place()
    K = intrinsics()
    for i in range(8):
        T = pose(CENTRE + [-1.5 + 0.4 * i, -0.5, 0.0], 20.0 * i, 10.0)
        frames.append(type(frames[0])(render_room(K, T), K, T, 10.0 + 0.1 * i))
    return frames


def mapped(law: str, changes_only: bool = False) -> tuple[Mapper, list[Patch], VoxelBlockGridBackend]:
    settings = MappingSettings(
        weight_law=law, patch_frames=5, patch_distance_m=50.0, patch_stretch=1, patch_changes_only=changes_only
    )
    mapper = Mapper(settings, producer=2, epoch=7, bounds=BOUNDS)
    single = VoxelBlockGridBackend(mapper.lattice, block_capacity=8192)
    patches = []
    for f in flight():
        single.integrate(f.depth, f.K, f.T, MAX_RANGE)
        sealed = mapper.integrate(f.depth, f.K, f.T, f.t, MAX_RANGE)
        if sealed:
            patches.append(sealed)
    last = mapper.seal()
    assert last is not None
    return mapper, patches + [last], single


@pytest.fixture(scope="module", params=["constant", "inverse_square", "dropoff"])
def flown(request):
    return request.param, *mapped(request.param)


def test_fused_patches_equal_one_tsdf_of_all_frames(flown) -> None:
    law, mapper, patches, single = flown
    assert len(patches) == 9  # 44 frames, 5 per patch
    fused = mapper.fused.arrays()
    whole = single.extract()
    observed = whole.weight.any(axis=1)
    assert np.array_equal(fused.keys, whole.keys[observed])
    w_single, t_single = whole.weight[observed], whole.tsdf[observed]
    seen = w_single > 0
    assert np.array_equal(fused.weight > 0, seen)
    if law == "constant":
        assert np.array_equal(fused.weight, w_single)  # integer counts, exact below 255 frames per patch
        tolerance = 0.5 / TSDF_SCALE + 1e-5
    else:
        unit = mapper.lattice.weight_unit
        assert np.abs(fused.weight - w_single).max() <= len(patches) * unit / 2 + 1e-4
        # weight rounding moves the weighted average by at most sum|dw| * max|t_p - t| / W
        tolerance = 0.5 / TSDF_SCALE + 1e-5 + (len(patches) * unit / 2) * 2.0 / np.maximum(fused.weight, unit)
    assert np.all(np.abs(fused.tsdf - t_single)[seen] <= np.broadcast_to(tolerance, seen.shape)[seen])


def test_fusion_does_not_depend_on_patch_order(flown) -> None:
    _, mapper, patches, _ = flown
    reference = mapper.fused
    for seed in range(3):
        shuffled = patches[:]
        random.Random(seed).shuffle(shuffled)
        other = FusedMap(mapper.lattice, BOUNDS, initial_blocks=16)  # also exercises pool growth
        for p in shuffled:
            assert other.add(p)
        assert other.digest() == reference.digest()  # integer sums: bit-identical, not just close
        a, b = other.arrays(), reference.arrays()
        assert all(np.array_equal(x, y) for x, y in zip(a, b))


def test_adding_a_patch_twice_changes_nothing(flown) -> None:
    _, mapper, patches, _ = flown
    before = mapper.fused.digest()
    assert not mapper.fused.add(patches[3])
    assert not mapper.receive(patches[3])
    assert mapper.fused.digest() == before
    assert mapper.fused.ids == frozenset(p.id for p in patches)


def test_open_patch_is_included_temporarily_and_removed_exactly() -> None:
    settings = MappingSettings(patch_frames=5)
    mapper = Mapper(settings, producer=1, epoch=1, bounds=BOUNDS)
    frames = rotate_in_place()[:7]
    for f in frames:
        mapper.integrate(f.depth, f.K, f.T, f.t, MAX_RANGE)
    assert len(mapper.private) == 1 and mapper.sealer.open_frames == 2
    (sealed,) = mapper.private.ids()
    assert mapper.private.data_bytes == len(mapper.private.data(sealed) or b"") > 0 and mapper.public.data_bytes == 0
    before, voxels = mapper.fused.digest(), mapper.fused.voxel_count
    with mapper.current_map() as view:
        assert view.voxel_count > voxels
        with_open = view.digest()
    assert mapper.fused.digest() == before and mapper.fused.voxel_count == voxels
    with mapper.current_map() as view:
        assert view.digest() == with_open


def test_blocks_outside_the_mission_volume_are_ignored() -> None:
    mapper, patches, _ = mapped("constant")
    small = FusedMap(mapper.lattice, (CENTRE - 1.0, CENTRE + 1.0))
    for p in patches:
        small.add(p)
    keys = small.arrays().keys
    lo, hi = small.lattice.block_bounds(keys)
    margin = small.lattice.block_size
    assert np.all(lo >= CENTRE - 1.0 - margin) and np.all(hi <= CENTRE + 1.0 + margin)
    assert 0.0 < small.known_fraction <= 1.0


def test_lattice_mismatch_is_refused(flown) -> None:
    _, _, patches, _ = flown
    other = FusedMap(Lattice(0.2, 8, 4.0), BOUNDS)
    with pytest.raises(ValueError):
        other.add(patches[0])


@pytest.mark.parametrize("law", ["constant", "dropoff"])
def test_changes_only_patches_give_the_states_of_sharing_every_observation(law: str) -> None:
    """One drone's map from changes-only patches reads as the map of every observation: each voxel is either in
    the map or held back, and held back only while sharing it would not change its state."""
    everything, all_patches, _ = mapped(law, changes_only=False)
    changes, patches, _ = mapped(law, changes_only=True)
    full, lean = everything.fused, changes.fused
    keys = full.block_keys()
    assert np.array_equal(lean.block_keys(), keys)
    r = full.lattice.block_resolution
    index = np.stack(np.meshgrid(*[np.arange(r)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    points = full.lattice.origin_array + (keys[:, None, :] * r + index).reshape(-1, 3) * full.lattice.voxel_size
    states, lean_states = full.state_at(points), lean.state_at(points)
    assert np.count_nonzero(states == OCCUPIED) > 1000 and np.count_nonzero(states == FREE) > 10000
    # Equal but on the surface itself, where sharing held-back observations as one (their mean tsdf rounded to
    # 1/127) can leave the sum on the other side of 0: both maps put those voxels within 1/50 of a truncation.
    differ = states != lean_states
    assert np.count_nonzero(differ) < 0.005 * len(points)
    keys_, flat = full.lattice.voxel_to_block(full.lattice.point_to_voxel(points[differ]))
    rows = np.arange(len(flat))
    for fused in (full, lean):
        weight, total = (a[rows, flat] for a in fused.sums(keys_))
        assert np.all(np.abs(total) <= 0.02 * TSDF_SCALE * weight)
    assert changes.unshared.held_back > 0.5 * sum(p.voxel_count for p in patches)
    own_bytes = sum(len(changes.data(p.id) or b"") for p in patches)
    all_bytes = sum(len(everything.data(p.id) or b"") for p in all_patches)
    assert own_bytes < 0.6 * all_bytes


def test_states_at_kept_voxel_addresses_are_the_states_at_the_points(flown) -> None:
    """`FusedMap.addresses`: the observer maps its reachable cells to voxels once and asks every map about them;
    the answer is `state_at` of the points, in maps that grow after the addresses were taken, points outside the
    bounds (unknown) included."""
    _, _, patches, _ = flown
    lattice = patches[0].lattice
    rng = np.random.default_rng(5)
    points = rng.uniform(BOUNDS[0] - 1.0, BOUNDS[1] + 1.0, (20000, 3))
    growing = FusedMap(lattice, BOUNDS)
    at = growing.addresses(points)
    assert 0 < len(at.inside) < len(points)
    for patch in patches:
        growing.add(patch)
        assert np.array_equal(growing.state_at(at), growing.state_at(points))
    states = growing.state_at(at)
    assert np.count_nonzero(states == FREE) > 100 and np.count_nonzero(states == OCCUPIED) > 10
    assert not states[np.setdiff1d(np.arange(len(points)), at.inside)].any()  # outside: UNKNOWN (0)
    with pytest.raises(ValueError, match="other bounds"):
        FusedMap(lattice, (BOUNDS[0], BOUNDS[1] + 3.0)).state_at(at)
