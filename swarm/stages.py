"""What each stage of an agent costs: calls, wall time per call (median, worst) and in all.

One `StageClock` per agent, shared by its threads (the mapping thread, the event loop, planning threads): a stage
is timed with `with clock.measure("integrate"): ...`. Durations are wall time on `time.perf_counter`, so a stage
that waits for a lock or is starved of a core shows it: on 2 busy cores that is what a drone's computer feels.

The median is over the last RECENT calls of each stage (a bounded window: a long mission's memory does not grow
with it); calls, total and worst are over the whole run. `StageClock()` with no stages recorded summarises to
`{}`; `NO_CLOCK` measures nothing, for code run without an agent (tests, tools).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

RECENT = 2048  # calls per stage the median is taken over


@dataclass
class _Stage:
    calls: int = 0
    total_s: float = 0.0
    max_s: float = 0.0
    recent: deque[float] = field(default_factory=lambda: deque(maxlen=RECENT))


class StageClock:
    def __init__(self, enabled: bool = True) -> None:
        self.enabled = enabled
        self._stages: dict[str, _Stage] = {}
        self._lock = threading.Lock()

    @contextmanager
    def measure(self, stage: str) -> Iterator[None]:
        """Time the block as one call of `stage` (also when it raises: a failed plan costs as much)."""
        if not self.enabled:
            yield
            return
        started = time.perf_counter()
        try:
            yield
        finally:
            self.record(stage, time.perf_counter() - started)

    def record(self, stage: str, seconds: float) -> None:
        if not self.enabled:
            return
        with self._lock:
            s = self._stages.setdefault(stage, _Stage())
            s.calls += 1
            s.total_s += seconds
            s.max_s = max(s.max_s, seconds)
            s.recent.append(seconds)

    def summary(self) -> dict[str, dict[str, float | int]]:
        """Per stage: calls, total_ms, p50_ms (the last RECENT calls), max_ms; stages in name order."""
        with self._lock:
            stages = {name: (s.calls, s.total_s, s.max_s, sorted(s.recent)) for name, s in self._stages.items()}
        return {
            name: {
                "calls": calls,
                "total_ms": round(1000 * total, 1),
                "p50_ms": round(1000 * recent[len(recent) // 2], 2),
                "max_ms": round(1000 * worst, 2),
            }
            for name, (calls, total, worst, recent) in sorted(stages.items())
        }


NO_CLOCK = StageClock(enabled=False)
