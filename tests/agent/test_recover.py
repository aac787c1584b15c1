"""Own patches of earlier runs come back from `agent.state_dir` (issue 7), and nothing else does."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from swarm.agent.mapping import recover_patches
from swarm.config import MappingSettings
from swarm.patches.mapper import Mapper
from swarm.patches.patch import PatchId

BOUNDS = (np.array([0.0, 0.0, 0.0]), np.array([4.0, 4.0, 3.0]))
MAX_BYTES = 1 << 20


def _sealed_patch(mapper: Mapper) -> tuple[PatchId, bytes]:
    """One real patch: a wall 2 m in front of a camera at (1, 2, 1.5) looking along +x."""
    depth = np.full((48, 64), 2.0, dtype=np.float32)
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
    recovered, rejected = recover_patches(tmp_path, second_life, MAX_BYTES)

    assert [p for p, _ in recovered] == [pid] and recovered[0][1] == data
    assert rejected == 2
    assert second_life.holds(pid) and not second_life.holds(other_pid)
    assert recover_patches(tmp_path, second_life, MAX_BYTES) == ([], 2)  # held already: not again
