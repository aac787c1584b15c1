"""`FusedMap.occupancy_grid` kept between calls: updated from the blocks that changed, equal to a full computation."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from swarm.config import MappingSettings
from swarm.patches.fused import OCCUPIED, FusedMap
from swarm.patches.lattice import Lattice
from swarm.patches.mapper import Mapper
from swarm.patches.patch import Patch
from tests.patches.scene import CENTRE, MAX_RANGE, ROOM_HI, ROOM_LO, Frame, intrinsics, pose, render_room

BOUNDS = (ROOM_LO - 2.0, ROOM_HI + 2.0)
GRIDS = ((0.2, 1.0), (0.2, 0.5), (0.1, 1.0))  # (resolution, min_known): the planning grid, a looser one, the fine


@pytest.fixture(scope="module")
def patches() -> tuple[Lattice, list[Patch]]:
    """Patches of a drone crossing the room while it turns: each adds blocks and changes some held ones."""
    settings = MappingSettings(patch_frames=3, patch_distance_m=50.0, patch_stretch=1)
    mapper = Mapper(settings, producer=1, epoch=1, bounds=BOUNDS)
    K = intrinsics()
    frames = []
    for i in range(12):
        T = pose(CENTRE + [-1.8 + 0.3 * i, -0.5, -0.3], 35.0 * i, 10.0)
        frames.append(Frame(render_room(K, T), K, T, 0.1 * i))
    sealed = [p for f in frames if (p := mapper.integrate(f.depth, f.K, f.T, f.t, MAX_RANGE)) is not None]
    assert len(sealed) == 4
    return mapper.lattice, sealed


def _fresh(lattice: Lattice, held: list[Patch]) -> FusedMap:
    fused = FusedMap(lattice, BOUNDS)
    for p in held:
        fused.add(p)
    return fused


def _assert_grids_equal(kept: FusedMap, reference: FusedMap) -> None:
    for resolution, min_known in GRIDS:
        got = kept.occupancy_grid(resolution, min_known=min_known)
        want = reference.occupancy_grid(resolution, min_known=min_known)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1], err_msg=f"{resolution} m, min_known {min_known}")


def test_kept_grids_equal_a_full_computation_after_every_patch_and_around_an_open_one(
    patches: tuple[Lattice, list[Patch]],
) -> None:
    lattice, sealed = patches
    kept = FusedMap(lattice, BOUNDS)
    _assert_grids_equal(kept, FusedMap(lattice, BOUNDS))  # empty
    for i, patch in enumerate(sealed):
        kept.add(patch)
        _assert_grids_equal(kept, _fresh(lattice, sealed[: i + 1]))
        if i + 1 < len(sealed):
            upcoming = sealed[i + 1]
            with kept.including(upcoming.blocks):  # the open patch: added for a decision, then removed
                _assert_grids_equal(kept, _fresh(lattice, sealed[: i + 2]))
            _assert_grids_equal(kept, _fresh(lattice, sealed[: i + 1]))


def test_a_caller_may_change_the_grid_it_was_given(patches: tuple[Lattice, list[Patch]]) -> None:
    lattice, sealed = patches
    kept = _fresh(lattice, sealed)
    _, states = kept.occupancy_grid(0.2)
    before = states.copy()
    states[...] = OCCUPIED  # e.g. a dead drone marked as an obstacle
    np.testing.assert_array_equal(kept.occupancy_grid(0.2)[1], before)


def test_an_update_reads_only_the_blocks_that_changed(
    patches: tuple[Lattice, list[Patch]], monkeypatch: pytest.MonkeyPatch
) -> None:
    lattice, sealed = patches
    kept = _fresh(lattice, sealed[:-1])
    kept.occupancy_grid(0.2)
    written: list[int] = []
    write = kept._write_cells

    def spy(out: np.ndarray, rows: np.ndarray, *args: Any) -> None:
        written.append(len(rows))
        write(out, rows, *args)

    monkeypatch.setattr(kept, "_write_cells", spy)
    kept.occupancy_grid(0.2)
    assert written == [], "nothing changed: nothing is read again"
    kept.add(sealed[-1])
    kept.occupancy_grid(0.2)
    assert written == [sealed[-1].block_count] and sealed[-1].block_count < kept.block_count
