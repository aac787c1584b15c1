"""Own patches of earlier runs come back from `agent.state_dir` (issue 7), and nothing else does; what a power cut
leaves of a file (empty, cut short) is skipped and counted, never fatal (issue 25)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from swarm.agent.mapping import recover_patches
from swarm.config import MappingSettings
from swarm.patches.mapper import Mapper
from swarm.patches.patch import PatchId

BOUNDS = (np.array([0.0, 0.0, 0.0]), np.array([4.0, 4.0, 3.0]))
MAX_BYTES = 1 << 20


def _sealed_patch(mapper: Mapper, distance: float = 2.0) -> tuple[PatchId, bytes]:
    """One real patch: a wall `distance` in front of a camera at (1, 2, 1.5) looking along +x."""
    depth = np.full((48, 64), distance, dtype=np.float32)
    K = np.array([[32.0, 0, 32], [0, 32.0, 24], [0, 0, 1]])
    T = np.array([[0, 0, 1, 1.0], [-1, 0, 0, 2.0], [0, -1, 0, 1.5], [0, 0, 0, 1]])  # camera z -> world x
    mapper.integrate(depth, K, T, 0.0, 4.0)
    patch = mapper.seal()
    assert patch is not None
    data = mapper.data(patch.id)
    assert data is not None
    return patch.id, data


def test_a_restarted_agent_fuses_its_earlier_patches_and_rejects_what_is_not_one(tmp_path: Path) -> None:
    settings = MappingSettings()
    first_life = Mapper(settings, producer=2, epoch=100, bounds=BOUNDS)
    pid, data = _sealed_patch(first_life)
    (tmp_path / f"{pid}.patch").write_bytes(data)
    other_drone = Mapper(settings, producer=3, epoch=100, bounds=BOUNDS)
    other_pid, other_data = _sealed_patch(other_drone)
    (tmp_path / f"{other_pid}.patch").write_bytes(other_data)  # not ours: left to the sync
    (tmp_path / "2.100.7.patch").write_bytes(b"\x00garbage")  # our name, bad bytes
    (tmp_path / "notes.patch").write_bytes(data)  # not a patch id

    second_life = Mapper(settings, producer=2, epoch=200, bounds=BOUNDS)
    found = recover_patches(tmp_path, second_life, MAX_BYTES)

    assert [p for p, _ in found.patches] == [pid] and found.patches[0][1] == data
    assert found.rejected == {"name": 1, "not_msgpack": 1}
    assert second_life.holds(pid) and not second_life.holds(other_pid)
    again = recover_patches(tmp_path, second_life, MAX_BYTES)  # held already: not again
    assert again.patches == [] and again.rejected == {"name": 1, "not_msgpack": 1}


def test_files_a_power_cut_left_empty_or_cut_short_are_skipped_and_counted(tmp_path: Path) -> None:
    settings = MappingSettings()
    first_life = Mapper(settings, producer=2, epoch=100, bounds=BOUNDS)
    whole, cut, emptied = (_sealed_patch(first_life, d) for d in (2.0, 2.5, 3.0))
    (tmp_path / f"{whole[0]}.patch").write_bytes(whole[1])
    (tmp_path / f"{emptied[0]}.patch").write_bytes(b"")  # the rename reached the disk, the data did not
    with open(tmp_path / f"{cut[0]}.patch", "wb") as f:  # written whole, then truncated on disk
        f.write(cut[1])
    os.truncate(tmp_path / f"{cut[0]}.patch", len(cut[1]) // 2)
    stale = tmp_path / ".2.100.9.patch.999999.tmp"  # `swarm.files.temp_path` of a process that died writing
    stale.write_bytes(whole[1][:100])

    second_life = Mapper(settings, producer=2, epoch=200, bounds=BOUNDS)
    found = recover_patches(tmp_path, second_life, MAX_BYTES)

    assert [p for p, _ in found.patches] == [whole[0]]
    assert sum(found.rejected.values()) == 2 and found.rejected.pop("empty_file") == 1
    assert found.rejected == {"not_msgpack": 1}  # the cut one: its msgpack document ends early
    assert not second_life.holds(cut[0]) and not second_life.holds(emptied[0])
    assert found.stale_temp == 1 and not stale.exists()
    assert (tmp_path / f"{cut[0]}.patch").exists()  # a rejected file is left as it is, for whoever looks


def test_a_file_larger_than_a_patch_can_be_is_not_read(tmp_path: Path) -> None:
    with open(tmp_path / "2.100.0.patch", "wb") as f:
        f.truncate(MAX_BYTES + 1)  # sparse: a lot of nothing
    found = recover_patches(tmp_path, Mapper(MappingSettings(), producer=2, epoch=200, bounds=BOUNDS), MAX_BYTES)
    assert found.patches == [] and found.rejected == {"too_large": 1}


def test_a_state_directory_that_is_gone_recovers_nothing(tmp_path: Path) -> None:
    found = recover_patches(tmp_path / "missing", Mapper(MappingSettings(), 2, 200, BOUNDS), MAX_BYTES)
    assert found.patches == [] and found.rejected == {} and found.stale_temp == 0
