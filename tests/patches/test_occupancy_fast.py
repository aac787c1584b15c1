"""`FusedMap.occupancy_grid`'s fast path (every coarse cell exactly f^3 voxels of one block) against its general
path: the same origin and states, on fused maps of several patches of the analytic room."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from swarm.config import MappingSettings
from swarm.patches.fused import FREE, OCCUPIED, UNKNOWN, FusedMap
from swarm.patches.lattice import Lattice
from swarm.patches.mapper import Mapper
from swarm.patches.patch import Patch
from tests.patches.scene import (
    CENTRE,
    MAX_RANGE,
    ROOM_HI,
    ROOM_LO,
    Frame,
    intrinsics,
    pose,
    render_room,
    rotate_in_place,
)

BOUNDS = (ROOM_LO - 2.0, ROOM_HI + 2.0)  # (-2, -2, -2)..(8, 7, 5): every block of the scene inside
SMALL = ((2.0, 1.6, 0.4), (4.0, 3.6, 2.4))  # inside the room, on the 0.4 m grid: the scene's blocks poke out
Box = tuple[Sequence[float], Sequence[float]]


def _frames() -> list[Frame]:
    """A turn in place, then a short pass across the room: patches that overlap in varied ways."""
    frames = rotate_in_place(yaws=8)
    K = intrinsics()
    for i in range(6):
        T = pose(CENTRE + [-1.5 + 0.5 * i, -0.6, -0.4], 30.0 * i, 15.0)
        frames.append(Frame(render_room(K, T), K, T, 10.0 + 0.1 * i))
    return frames


@pytest.fixture(scope="module")
def patches() -> tuple[Lattice, list[Patch]]:
    settings = MappingSettings(patch_frames=5, patch_distance_m=50.0, patch_stretch=1, patch_changes_only=False)
    mapper = Mapper(settings, producer=1, epoch=1, bounds=BOUNDS)
    sealed = [p for f in _frames() if (p := mapper.integrate(f.depth, f.K, f.T, f.t, MAX_RANGE)) is not None]
    assert len(sealed) == 6 and mapper.seal() is None  # 30 frames, 5 per patch: none left open
    return mapper.lattice, sealed


def _fused(patches: tuple[Lattice, list[Patch]], bounds: Box = BOUNDS, known_weight: float = 1.0) -> FusedMap:
    lattice, held = patches
    fused = FusedMap(lattice, bounds, known_weight)
    for p in held:
        assert fused.add(p)
    return fused


def _both_paths(
    fused: FusedMap,
    resolution: float,
    lo: Sequence[float] | None,
    hi: Sequence[float] | None,
    monkeypatch: pytest.MonkeyPatch,
    min_known: float = 1.0,
) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """(fast, general) results of `occupancy_grid`, checking that each ran the path it is named after."""
    calls: list[int] = []
    aligned = fused._occupancy_aligned

    def spy(f: int, *args: Any) -> np.ndarray:
        calls.append(f)
        return aligned(f, *args)

    def refuse(*args: Any) -> np.ndarray:
        raise AssertionError("the general path was forced")

    with monkeypatch.context() as m:
        m.setattr(fused, "_occupancy_aligned", spy)
        fast = fused.occupancy_grid(resolution, lo, hi, min_known=min_known)
    assert calls == [round(resolution / fused.lattice.voxel_size)]
    with monkeypatch.context() as m:
        m.setattr(fused, "_aligned_cells", lambda resolution, lo: None)
        m.setattr(fused, "_occupancy_aligned", refuse)
        general = fused.occupancy_grid(resolution, lo, hi, min_known=min_known)
    return fast, general


def _assert_same(fast: tuple[np.ndarray, np.ndarray], general: tuple[np.ndarray, np.ndarray]) -> None:
    assert fast[0].dtype == general[0].dtype == np.float64
    np.testing.assert_array_equal(fast[0], general[0])
    assert fast[1].dtype == general[1].dtype == np.uint8
    assert fast[1].shape == general[1].shape
    np.testing.assert_array_equal(fast[1], general[1])


def _counts(states: np.ndarray) -> list[int]:
    return np.bincount(states.ravel(), minlength=3).tolist()


def _blocks_poke_out(fused: FusedMap, lo: np.ndarray, shape: tuple[int, ...], resolution: float) -> bool:
    """Some held block reaches outside the cells [lo, lo + shape * resolution)."""
    block_lo, block_hi = fused.lattice.block_bounds(fused.arrays().keys)
    hi = lo + np.array(shape) * resolution
    return bool(np.any(block_lo < lo - 1e-9) or np.any(block_hi > hi + 1e-9))


# (lo, hi, whether some blocks reach outside the cells) per case: the default volume (the mission bounds, 2 m
# around the room: every block inside); one cutting through the blocks, with z = -0.2 (on the 0.2 m grid only)
# or -0.4; one a block wider than the bounds; one whose hi is not a whole number of cells from lo, across the
# corner of two walls; one far from any block.
CASES = {
    "bounds": (None, None, False),
    "through blocks": ((-1.2, -0.8, -0.2), (7.2, 6.0, 3.4), True),
    "through blocks, z -0.4": ((-1.2, -0.8, -0.4), (7.2, 6.0, 3.4), True),
    "around every block": ((-2.4, -2.4, -2.4), (8.8, 8.0, 5.6), False),
    "ragged hi": ((4.0, 2.8, 0.4), (6.9, 5.7, 2.3), True),
    "far away": ((20.0, 20.0, 20.0), (22.0, 21.2, 20.8), True),
}


@pytest.mark.parametrize("min_known", [1.0, 0.5])
@pytest.mark.parametrize("known_weight", [1.0, 3.0])
@pytest.mark.parametrize(
    ("case", "resolution"),
    [(case, r) for case in CASES for r in (0.1, 0.2, 0.4) if (case, r) != ("through blocks", 0.4)],  # z -0.2: off 0.4 m
)
def test_the_fast_path_equals_the_general_path_on_a_fused_map(
    patches: tuple[Lattice, list[Patch]],
    monkeypatch: pytest.MonkeyPatch,
    case: str,
    resolution: float,
    known_weight: float,
    min_known: float,
) -> None:
    lo, hi, poke = CASES[case]
    fused = _fused(patches, known_weight=known_weight)
    assert len(patches[1]) >= 5 and fused.block_count > 100
    lo_ = fused.bounds[0] if lo is None else np.asarray(lo, dtype=float)
    assert fused._aligned_cells(resolution, lo_) is not None
    fast, general = _both_paths(fused, resolution, lo, hi, monkeypatch, min_known)
    _assert_same(fast, general)
    np.testing.assert_array_equal(fast[0], lo_)
    counts = _counts(fast[1])
    if case == "far away":
        assert counts[FREE] == counts[OCCUPIED] == 0 and counts[UNKNOWN] > 0
    else:
        assert min(counts) > 50, counts  # the room's free air, its walls, and unknown space all show
    # Both branches of the fast path's clipping: every block inside the cells, or some reaching outside them.
    assert _blocks_poke_out(fused, lo_, fast[1].shape, resolution) == poke
    if case == "ragged hi":
        assert fast[1].shape == tuple(int(np.ceil(n / resolution)) for n in (2.9, 2.9, 1.9))


@pytest.mark.parametrize("resolution", [0.2, 0.4])
def test_the_fast_path_clips_blocks_poking_out_of_a_small_volume(
    patches: tuple[Lattice, list[Patch]], monkeypatch: pytest.MonkeyPatch, resolution: float
) -> None:
    small = _fused(patches, SMALL)
    whole = _fused(patches)
    assert 0 < small.block_count < whole.block_count
    lo = np.array(SMALL[0])
    # Blocks are whole: the small map holds voxels below and beyond its volume, on every axis at one end at least,
    # among them the floor (z = 0, occupied) under its volume (z >= 0.4 m) and free air beside it (x < 2 m).
    block_lo, block_hi = small.lattice.block_bounds(small.arrays().keys)
    assert np.all((block_lo.min(axis=0) < lo - 1e-9) | (block_hi.max(axis=0) > np.array(SMALL[1]) + 1e-9))
    assert small.state_at(np.array([[3.0, 2.5, 0.0], [1.7, 2.5, 1.0]])).tolist() == [OCCUPIED, FREE]
    # Its own volume and a smaller one: blocks poke out, and nothing of the floor may leak in. A volume larger
    # than its own: every block inside the cells, the floor among them, and cells beyond its blocks.
    cases: list[tuple[Box | tuple[None, None], bool]] = [
        ((None, None), True),
        ((SMALL[0], (3.6, 3.2, 2.0)), True),
        (((0.8, 0.8, -0.4), (5.2, 4.4, 3.6)), False),
    ]
    for (case_lo, case_hi), poke in cases:
        fast, general = _both_paths(small, resolution, case_lo, case_hi, monkeypatch)
        _assert_same(fast, general)
        assert _blocks_poke_out(small, fast[0], fast[1].shape, resolution) == poke
        counts = _counts(fast[1])
        assert counts[FREE] > 50 and counts[UNKNOWN] > 0
        assert (counts[OCCUPIED] > 50) if not poke else (counts[OCCUPIED] == 0)
    # Inside its volume, the small map agrees with the whole one (same voxels, same sums).
    _, states = small.occupancy_grid(resolution)
    _, reference = whole.occupancy_grid(resolution, SMALL[0], SMALL[1])
    np.testing.assert_array_equal(states, reference)


@pytest.mark.parametrize(
    ("resolution", "min_known"),
    [
        (0.2, 1.0),
        (0.4, 1.0),
        (0.8, 1.0),  # one cell per block
        (0.2, 0.5),
        (0.4, 0.5),
        (0.4, 0.9),
        (0.8, 0.5),  # 512 voxels a cell: the count must not wrap
    ],
)
def test_both_paths_are_the_voxel_states_reduced_cell_by_cell(
    patches: tuple[Lattice, list[Patch]], monkeypatch: pytest.MonkeyPatch, resolution: float, min_known: float
) -> None:
    # At the voxel size each cell is one voxel; a coarse cell is OCCUPIED if any of its voxels is, FREE if at
    # least min_known of them are known (FREE) and none is OCCUPIED, UNKNOWN otherwise. With known_weight 3 many
    # cells are partly known.
    fused = _fused(patches, known_weight=3.0)
    lo, hi = (-1.6, -1.6, -0.8), (7.2, 6.4, 4.0)  # on the 0.8 m grid, a whole number of 0.8 m cells
    fast_voxels, general_voxels = _both_paths(fused, 0.1, lo, hi, monkeypatch)
    _assert_same(fast_voxels, general_voxels)
    voxels = fast_voxels[1]
    # lo is on the lattice: cell i holds the voxel whose sample point is lo + i * 0.1; check every 997th one.
    sampled = np.argwhere(np.ones(voxels.shape, dtype=bool))[::997]
    np.testing.assert_array_equal(fused.state_at(fast_voxels[0] + sampled * 0.1), voxels[tuple(sampled.T)])
    f = round(resolution / 0.1)
    n = tuple(s // f for s in voxels.shape)
    split = voxels.reshape(n[0], f, n[1], f, n[2], f)
    any_occupied = (split == OCCUPIED).any(axis=(1, 3, 5))
    free_voxels = (split == FREE).sum(axis=(1, 3, 5))
    enough_known = free_voxels >= min_known * f**3
    expected = np.where(any_occupied, OCCUPIED, np.where(enough_known, FREE, UNKNOWN)).astype(np.uint8)
    partly_known = ~any_occupied & (free_voxels > 0) & (free_voxels < f**3)
    assert partly_known.sum() > 20  # cells where min_known decides: some voxels FREE, others UNKNOWN
    if min_known < 1.0:
        assert np.any(partly_known & enough_known)  # and some it makes FREE
    fast, general = _both_paths(fused, resolution, lo, hi, monkeypatch, min_known)
    np.testing.assert_array_equal(general[1], expected)
    np.testing.assert_array_equal(fast[1], expected)
    _assert_same(fast, general)


@pytest.mark.parametrize(
    ("resolution", "lo"),
    [
        (0.4, (-1.2, -0.8, -0.2)),  # z = -0.2 m: on the 0.2 m grid, half a cell off the 0.4 m one
        (0.2, (-1.2, -0.8, -0.1)),  # on the voxel lattice, half a cell off
        (0.2, (-1.15, -0.8, -0.2)),  # off the voxel lattice
        (0.25, (-1.0, -1.0, -0.5)),  # 2.5 voxels per cell
        (0.3, (-1.2, -0.6, -0.3)),  # 3 voxels per cell: a block of 8 is not whole cells
    ],
)
def test_a_volume_off_the_cell_grid_takes_the_general_path(
    patches: tuple[Lattice, list[Patch]], monkeypatch: pytest.MonkeyPatch, resolution: float, lo: tuple[float, ...]
) -> None:
    fused = _fused(patches)
    assert fused._aligned_cells(resolution, np.asarray(lo)) is None

    def refuse(f: int, offset: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
        raise AssertionError("the fast path ran on a volume off its grid")

    monkeypatch.setattr(fused, "_occupancy_aligned", refuse)
    origin, states = fused.occupancy_grid(resolution, lo, (7.2, 6.0, 3.4))
    np.testing.assert_array_equal(origin, lo)
    assert states.dtype == np.uint8 and min(_counts(states)) > 50


@pytest.mark.parametrize("resolution", [0.2, 0.4])
def test_an_empty_map_is_unknown_on_both_paths(monkeypatch: pytest.MonkeyPatch, resolution: float) -> None:
    fused = FusedMap(Lattice(0.1, 8, 4.0), BOUNDS)
    for lo, hi in ((None, None), ((-1.2, -0.8, -0.4), (7.2, 6.0, 3.4))):
        fast, general = _both_paths(fused, resolution, lo, hi, monkeypatch)
        _assert_same(fast, general)
        assert fast[1].size > 0 and not fast[1].any()
