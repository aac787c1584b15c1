"""The observer's map: patch files are decoded like received patches; a bad one is counted and never fused."""

from __future__ import annotations

from pathlib import Path

from swarm.config import load_config
from swarm.mission.coverage import SwarmCoverage
from tests.mission.spin_patches import spin_patches


def test_corrupt_patch_files_are_counted_and_never_fused(tmp_path: Path) -> None:
    config = load_config(None, {"mission.world": "box", "mapping.patch_frames": 6})
    good = spin_patches(config, producer=1, epoch=7)
    assert len(good) == 2
    (tmp_path / "a.patch").write_bytes(good[0])
    flipped = bytearray(good[1])
    flipped[len(flipped) // 2] ^= 0xFF
    (tmp_path / "b.patch").write_bytes(bytes(flipped))
    (tmp_path / "c.patch").write_bytes(good[1][: len(good[1]) // 3])

    coverage = SwarmCoverage(config, tmp_path)
    coverage.update(t=1.0)
    snapshot = coverage.snapshot()
    assert snapshot["patches_fused"] == 1
    assert sum(snapshot["patches_rejected"].values()) == 2
    only_good = coverage.fused.digest()
    first = coverage.fraction
    assert 0.0 < first < 1.0

    (tmp_path / "d.patch").write_bytes(good[1])  # the intact version arrives later
    coverage.update(t=2.0)
    assert coverage.snapshot()["patches_fused"] == 2
    assert coverage.fused.digest() != only_good
    assert coverage.fraction > first
    assert [t for t, _ in coverage.snapshot()["explored_timeline"]] == [1.0, 2.0]


def test_the_patch_bytes_count_each_fused_patch_once_and_the_map_size_is_taken_at_the_end(tmp_path: Path) -> None:
    config = load_config(None, {"mission.world": "box", "mapping.patch_frames": 6})
    good = spin_patches(config, producer=1, epoch=7)
    (tmp_path / "a.patch").write_bytes(good[0])
    (tmp_path / "b.patch").write_bytes(good[1][:-5])  # cut short: refused, not counted
    coverage = SwarmCoverage(config, tmp_path)
    coverage.update(t=1.0)
    assert coverage.snapshot()["patch_bytes"] == len(good[0])
    assert coverage.snapshot()["map_bytes"] == 0, "the whole map is measured only at the end"

    (tmp_path / "c.patch").write_bytes(good[1])
    (tmp_path / "d.patch").write_bytes(good[0])  # the same patch again under another name: fused once
    coverage.update(t=2.0, final=True)
    snapshot = coverage.snapshot()
    assert snapshot["patch_bytes"] == len(good[0]) + len(good[1])
    assert snapshot["map_bytes"] == coverage.fused.wire_size() > 0
