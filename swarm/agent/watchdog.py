"""Is the autopilot's telemetry lost, or did this process just not hear it?

Telemetry reaches the agent through its event loop (MAVSDK's threads hand every sample to a loop callback), so
while the loop does not run (the process is stopped, starved of CPU by other load, or blocked by its own work)
samples queue up unread and the cache grows old although the link is fine. Such a gap is no evidence of a lost
link. The watchdog therefore counts silence only over the time the loop was awake to hear: `LoopMonitor` wakes
every `LOOP_PERIOD_S` and records each wake-up that came more than `LATE_AFTER_S` late as deaf time, and
`heard_silence` is the telemetry's age minus the deaf time since the last sample. The failsafe fires once that
reaches the telemetry timeout, so a link that really stops is still judged lost after `telemetry_timeout_s` of
listening, however late the loop ran before.

Wake-ups up to `LATE_AFTER_S` late count as listening: a loop that is always a little late (a busy agent) does
not postpone the failsafe, a stall does.
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Callable

LOOP_PERIOD_S = 0.05
LATE_AFTER_S = 0.2  # a wake-up later than this: the loop did not run meanwhile (deaf)
KEEP_S = 120.0  # deaf spans older than this are forgotten (a silence that long has been judged already)


class DeafTime:
    """Spans of time during which this process's event loop did not run."""

    def __init__(self) -> None:
        self._spans: deque[tuple[float, float]] = deque()  # (start, end), end increasing

    def add(self, start: float, end: float) -> None:
        if end > start:
            self._spans.append((start, end))
            while self._spans and self._spans[0][1] < end - KEEP_S:
                self._spans.popleft()

    def since(self, t: float) -> float:
        """Seconds of deaf time after `t`."""
        return sum(end - max(start, t) for start, end in self._spans if end > t)


class LoopMonitor:
    """A task that measures its own lateness and records it as deaf time.

    A check made while the monitor is itself overdue (the loop has just woken, and the code asking runs before
    the monitor's wake-up) counts the overdue time as deaf too: queued telemetry may not have been read yet.
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.deaf = DeafTime()
        self.clock = clock
        self.worst_late_s = 0.0
        self._due: float | None = None  # when the monitor should wake next; None when it is not running

    def note(self, due: float, woke: float) -> None:
        late = woke - due
        self.worst_late_s = max(self.worst_late_s, late)
        if late > LATE_AFTER_S:
            self.deaf.add(due, woke)

    def heard_silence(self, now: float, last_sample: float) -> float:
        """How long this process listened, awake, since the last telemetry sample at `last_sample`."""
        deaf = self.deaf.since(last_sample)
        if self._due is not None and now - self._due > LATE_AFTER_S:
            deaf += now - max(self._due, last_sample)
        return max(0.0, now - last_sample - deaf)

    async def run(self) -> None:
        try:
            while True:
                self._due = self.clock() + LOOP_PERIOD_S
                await asyncio.sleep(LOOP_PERIOD_S)
                self.note(self._due, self.clock())
        finally:
            self._due = None
