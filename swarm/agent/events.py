"""The agent's structured event log: one JSON object per line on stdout (and in the run's log file).

Lines are meant for people and for tools alike: tests and the observer read them to know when an agent saw a
peer join or leave, changed phase or failed safe.
"""

from __future__ import annotations

import json
import sys
import time
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
