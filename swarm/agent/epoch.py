"""The agent's epoch: a number no earlier process of this drone used, and larger than theirs.

Patch ids are (producer, epoch, seq), and seq starts again at 0 in every process: an epoch used twice would give
two different patches one id, and a peer that holds the first takes the second for it (it is never pulled,
never fused). Heartbeats, frontier reports and assignments carry the epoch too, and the harness and its tests read
"a restarted agent rejoins with a new epoch" as a larger one. So the epoch is a counter that only grows:

    epoch = max(now_ms, previous + 1)

`now_ms` is the wall clock in milliseconds (what the epoch always was, so epochs stay readable as start times
while the clock is right); `previous` is the largest epoch this drone is known to have used: the one in
`<agent.state_dir>/epoch.json`, written durably before the epoch is used, or the largest in the names of the own
patch files there (they survive a lost or damaged epoch file). A companion computer without a real-time clock
that boots to the same or an earlier time still gets a new, larger epoch.

Without `agent.state_dir` nothing is remembered and the epoch is `now_ms`: unique only while the clock never
repeats a millisecond across restarts (an NTP-, GPS- or RTC-set clock). A drone without a real-time clock must
set `agent.state_dir` (`swarm run` always does).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from pydantic import Field

from swarm.files import FileFormatError, FileModel, read_model, write_model
from swarm.patches.patch import PatchId

EPOCH_FILE = "epoch.json"
MAX_EPOCH = 2**63 - 1  # the wire's Counter bound


class EpochFile(FileModel):
    """The last epoch this drone's agent took (`<agent.state_dir>/epoch.json`)."""

    epoch: int = Field(ge=0, lt=MAX_EPOCH)


def next_epoch(state_dir: Path | None, producer: int, now_ms: int, log: Callable[..., Any]) -> int:
    """A new epoch for agent `producer` (see the module doc), recorded in `state_dir` before it is returned; a
    state directory that cannot be read or written is logged and the epoch taken all the same."""
    if state_dir is None:
        return now_ms
    previous = max([*_recorded(state_dir, log), *_in_patch_names(state_dir, producer)], default=None)
    epoch = now_ms if previous is None else max(now_ms, previous + 1)
    try:
        state_dir.mkdir(parents=True, exist_ok=True)
        write_model(state_dir / EPOCH_FILE, EpochFile(epoch=epoch), indent=None, durable=True)
    except (OSError, ValueError) as exc:  # ValueError: beyond MAX_EPOCH, which no clock reaches
        log("epoch_store_failed", state_dir=str(state_dir), epoch=epoch, error=str(exc))
    return epoch


def _recorded(state_dir: Path, log: Callable[..., Any]) -> list[int]:
    try:
        return [read_model(state_dir / EPOCH_FILE, EpochFile).epoch]
    except FileNotFoundError:
        return []
    except (OSError, FileFormatError) as exc:
        log("epoch_file_unusable", path=str(state_dir / EPOCH_FILE), error=str(exc))
        return []


def _in_patch_names(state_dir: Path, producer: int) -> list[int]:
    epochs = []
    try:
        names = [p.stem for p in state_dir.glob("*.patch")]
    except OSError:
        return []
    for name in names:
        try:
            pid = PatchId.parse(name)
        except ValueError:
            continue
        if pid.producer == producer and pid.epoch < MAX_EPOCH:
            epochs.append(pid.epoch)
    return epochs
