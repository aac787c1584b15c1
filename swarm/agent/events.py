"""The agent's structured event log: one JSON object per line on stdout (and in the run's log file).

Lines are meant for people and for tools alike: tests and the observer read them to know when an agent saw a
peer join or leave, changed phase or failed safe.
"""

from __future__ import annotations

import asyncio
import json
import sys
import time
from collections.abc import Callable
from typing import IO, Any


class EventLog:
    def __init__(self, agent_id: int, stream: IO[str] | None = None) -> None:
        self.agent_id = agent_id
        self.stream = stream or sys.stdout

    def __call__(self, event: str, **fields: Any) -> None:
        record = {"t": round(time.time(), 3), "agent": self.agent_id, "event": event, **fields}
        try:
            self.stream.write(json.dumps(record, default=str) + "\n")
            self.stream.flush()
        except (OSError, ValueError):
            pass  # a closed stdout must not take the drone down


def log_if_failed(task: asyncio.Task[Any], log: Callable[..., None]) -> asyncio.Task[Any]:
    """`task`, which now logs `task_failed` (its name and error) the moment it ends with an exception. The agent
    awaits its background tasks only at exit, and then without their exceptions: a task that died in flight (the
    mapping, the heartbeat) would otherwise stop unseen while the drone flies on."""

    def on_done(done: asyncio.Task[Any]) -> None:
        if not done.cancelled() and (exc := done.exception()) is not None:
            log("task_failed", task=done.get_name(), error=" ".join(f"{type(exc).__name__}: {exc}".split()))

    task.add_done_callback(on_done)
    return task
