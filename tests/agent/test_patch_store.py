"""A sealed patch that cannot be written to disk is logged, counted and still pushed and fused (issue 25)."""

from __future__ import annotations

import asyncio
import errno
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from swarm.agent import mapping as mapping_module
from swarm.agent.mapping import MappingTask
from swarm.agent.summary import AgentSummary
from swarm.config import SwarmConfig
from swarm.patches.patch import PatchId
from tests.file_models import agent_summary_data

BOUNDS = (np.array([0.0, 0.0, 0.0]), np.array([4.0, 4.0, 3.0]))
K = np.array([[32.0, 0, 32], [0, 32.0, 24], [0, 0, 1]])
T = np.array([[0, 0, 1, 1.0], [-1, 0, 0, 2.0], [0, -1, 0, 1.5], [0, 0, 0, 1]])  # at (1, 2, 1.5), looking along +x


class NoSource:
    """A stream source that is never started: these tests feed frames to the mapper themselves."""

    def start(self) -> None:
        raise AssertionError("not used")

    def wait_frame(self, timeout_s: float) -> None:
        return None

    def counters(self) -> dict[str, int]:
        return {}

    def close(self) -> None:
        pass


class Log:
    def __init__(self) -> None:
        self.events: list[dict[str, Any]] = []

    def __call__(self, event: str, **fields: Any) -> None:
        self.events.append({"event": event, **fields})

    def named(self, event: str) -> list[dict[str, Any]]:
        return [e for e in self.events if e["event"] == event]


def _task(state_dir: Path, out_dir: Path | None, log: Log, sealed: list[tuple[PatchId, bytes]]) -> MappingTask:
    # every seal a patch (changes only would seal nothing where the same wall is seen again)
    config = SwarmConfig.model_validate(
        {"agent": {"id": 2, "state_dir": str(state_dir)}, "mapping": {"patch_changes_only": False}}
    )
    return MappingTask(
        config, 100, NoSource(), BOUNDS, log, out_dir, on_sealed=lambda pid, data: sealed.append((pid, data))
    )


def _seal_one(task: MappingTask, distance: float = 2.0) -> None:
    """A wall `distance` in front of the camera, sealed as the agent does after landing (in the mapping thread)."""
    task.mapper.integrate(np.full((48, 64), distance, dtype=np.float32), K, T, 0.0, 4.0)
    asyncio.run(task.seal_last())


def test_a_sealed_patch_is_stored_durably_and_pushed(tmp_path: Path) -> None:
    log, sealed = Log(), []
    task = _task(tmp_path / "state", tmp_path / "out", log, sealed)
    _seal_one(task)
    [(pid, data)] = sealed
    assert (tmp_path / "state" / f"{pid}.patch").read_bytes() == data
    assert (tmp_path / "out" / "patches" / f"{pid}.patch").read_bytes() == data
    assert sorted(p.name for p in (tmp_path / "state").iterdir()) == [f"{pid}.patch"]  # no temp file left
    assert task.summary()["patch_store_failures"] == {} and not log.named("patch_store_failed")


def test_a_full_disk_is_logged_and_counted_and_the_patch_is_still_pushed_and_fused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_space(path: Path, data: bytes) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(mapping_module, "write_durable", no_space)
    log, sealed = Log(), []
    task = _task(tmp_path / "state", None, log, sealed)
    _seal_one(task)
    _seal_one(task, distance=3.0)  # mapping went on after the first failure

    assert [pid.seq for pid, _ in sealed] == [0, 1]  # both pushed
    assert all(pid in task.mapper.fused for pid, _ in sealed)  # and fused
    failed = log.named("patch_store_failed")
    assert [(e["patch"], e["errno"]) for e in failed] == [(str(pid), "ENOSPC") for pid, _ in sealed]
    summary = task.summary()
    assert summary["patch_store_failures"] == {"ENOSPC": 2} and summary["patches_sealed"] == 2
    # the count reaches the summary file the harness reads
    data = agent_summary_data(**{k: v for k, v in summary.items() if k in AgentSummary.model_fields})
    assert AgentSummary.model_validate(data).patch_store_failures == {"ENOSPC": 2}


def test_a_write_that_fails_leaves_no_temp_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from swarm import files

    def fails(fd: int) -> None:
        raise OSError(errno.EIO, os.strerror(errno.EIO))

    monkeypatch.setattr(files.os, "fsync", fails)
    with pytest.raises(OSError, match="Input/output error"):
        files.write_durable(tmp_path / "1.2.3.patch", b"x" * 1000)
    assert list(tmp_path.iterdir()) == []


# --- a real full disk: a 64 KiB tmpfs (root) --------------------------------------------------------------


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    mount = tmp_path / "disk"
    mount.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount)], check=True)
    try:
        yield mount
    finally:
        subprocess.run(["umount", str(mount)], check=True)


@pytest.mark.netns
def test_on_a_disk_that_fills_up_every_patch_is_still_pushed_and_the_failures_are_counted(small_disk: Path) -> None:
    log, sealed = Log(), []
    task = _task(small_disk / "state", None, log, sealed)
    seals = 0
    while not log.named("patch_store_failed") and seals < 200:
        _seal_one(task, distance=1.5 + 0.01 * seals)
        seals += 1
    _seal_one(task, distance=3.5)  # and once more on the full disk

    assert len(sealed) == seals + 1 == task.patches_sealed  # every patch pushed
    stored = {p.name for p in (small_disk / "state").iterdir()}
    failed = {e["patch"] for e in log.named("patch_store_failed")}
    assert failed and {e["errno"] for e in log.named("patch_store_failed")} == {"ENOSPC"}
    assert stored == {f"{pid}.patch" for pid, _ in sealed if str(pid) not in failed}  # whole files only, no temp
    assert task.summary()["patch_store_failures"] == {"ENOSPC": len(failed)}
    for pid, data in sealed:
        assert pid in task.mapper.fused
        if str(pid) not in failed:
            assert (small_disk / "state" / f"{pid}.patch").read_bytes() == data
