"""An agent's epoch is never one an earlier process of its drone used, and is larger, whatever the clock says
(issue 25: a companion computer without a real-time clock boots to the same time again)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from swarm.agent.epoch import EPOCH_FILE, EpochFile, next_epoch
from swarm.config import SwarmConfig
from swarm.files import read_model

NOW = 1_795_340_000_000  # ms


class Log:
    def __init__(self) -> None:
        self.events: list[tuple[str, dict[str, Any]]] = []

    def __call__(self, event: str, **fields: Any) -> None:
        self.events.append((event, fields))


def test_restarts_on_a_clock_that_booted_to_the_same_time_get_new_larger_epochs(tmp_path: Path) -> None:
    log = Log()
    epochs = [next_epoch(tmp_path, 2, NOW, log) for _ in range(3)]
    assert epochs == [NOW, NOW + 1, NOW + 2]
    assert read_model(tmp_path / EPOCH_FILE, EpochFile).epoch == NOW + 2
    assert log.events == []


def test_a_clock_that_went_back_still_gives_a_larger_epoch_and_a_right_clock_wins_again(tmp_path: Path) -> None:
    first = next_epoch(tmp_path, 2, NOW, Log())
    assert next_epoch(tmp_path, 2, 5_000, Log()) == first + 1  # booted near 1970
    assert next_epoch(tmp_path, 2, NOW + 60_000, Log()) == NOW + 60_000  # the clock is right again: its time


def test_own_patch_files_count_when_the_epoch_file_is_lost_or_damaged(tmp_path: Path) -> None:
    (tmp_path / f"2.{NOW + 500}.3.patch").write_bytes(b"")  # ours, even if empty: its name was used
    (tmp_path / f"3.{NOW + 900}.0.patch").write_bytes(b"")  # another drone's
    (tmp_path / "notes.patch").write_bytes(b"")
    assert next_epoch(tmp_path, 2, NOW, Log()) == NOW + 501  # no epoch file at all

    (tmp_path / EPOCH_FILE).write_text('{"epoch": ')  # damaged
    log = Log()
    assert next_epoch(tmp_path, 2, NOW, log) == NOW + 501
    assert [event for event, _ in log.events] == ["epoch_file_unusable"]
    assert read_model(tmp_path / EPOCH_FILE, EpochFile).epoch == NOW + 501  # and mended


def test_without_a_state_directory_the_epoch_is_the_clock(tmp_path: Path) -> None:
    assert next_epoch(None, 2, NOW, Log()) == NOW


def test_a_state_directory_that_cannot_be_written_is_logged_and_the_epoch_taken_all_the_same(tmp_path: Path) -> None:
    blocked = tmp_path / "file"
    blocked.write_bytes(b"")  # a file where the directory should be: mkdir fails, whoever we are
    log = Log()
    assert next_epoch(blocked / "state", 2, NOW, log) == NOW
    assert [event for event, _ in log.events] == ["epoch_file_unusable", "epoch_store_failed"]


def test_two_agent_processes_started_at_the_same_millisecond_take_different_epochs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from swarm.agent import main

    monkeypatch.setattr(main.time, "time_ns", lambda: NOW * 1_000_000)
    config = SwarmConfig.model_validate({"agent": {"id": 2, "state_dir": str(tmp_path)}})
    assert [main.Agent(config).epoch for _ in range(2)] == [NOW, NOW + 1]
