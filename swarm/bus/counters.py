"""Traffic counters per message kind, updated from Zenoh threads, the event loop and writer threads."""

from __future__ import annotations

import threading
from collections import Counter
from dataclasses import dataclass, field
from typing import Any


@dataclass
class _KindCounts:
    sent_msgs: int = 0
    sent_bytes: int = 0
    recv_msgs: int = 0
    recv_bytes: int = 0
    dropped: Counter[str] = field(default_factory=Counter)


class TrafficCounters:
    """Messages and bytes sent and received, and messages dropped with a reason, per message kind.

    Received counts every payload that arrived, valid or not; a payload that is then rejected is also
    counted under `dropped` with the reason (a `DecodeError` reason, or e.g. "handler_error", "backlog").
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._kinds: dict[str, _KindCounts] = {}

    def _get(self, kind: str) -> _KindCounts:
        counts = self._kinds.get(kind)
        if counts is None:
            counts = self._kinds[kind] = _KindCounts()
        return counts

    def sent(self, kind: str, nbytes: int) -> None:
        with self._lock:
            counts = self._get(kind)
            counts.sent_msgs += 1
            counts.sent_bytes += nbytes

    def received(self, kind: str, nbytes: int) -> None:
        with self._lock:
            counts = self._get(kind)
            counts.recv_msgs += 1
            counts.recv_bytes += nbytes

    def dropped(self, kind: str, reason: str) -> None:
        with self._lock:
            self._get(kind).dropped[reason] += 1

    def dropped_count(self, kind: str, reason: str | None = None) -> int:
        with self._lock:
            counts = self._kinds.get(kind)
            if counts is None:
                return 0
            return counts.dropped[reason] if reason is not None else sum(counts.dropped.values())

    @property
    def bytes_sent(self) -> int:
        with self._lock:
            return sum(c.sent_bytes for c in self._kinds.values())

    @property
    def bytes_received(self) -> int:
        with self._lock:
            return sum(c.recv_bytes for c in self._kinds.values())

    def snapshot(self) -> dict[str, dict[str, Any]]:
        """A JSON-ready copy: {kind: {sent_msgs, sent_bytes, recv_msgs, recv_bytes, dropped: {reason: n}}}."""
        with self._lock:
            return {
                kind: {
                    "sent_msgs": c.sent_msgs,
                    "sent_bytes": c.sent_bytes,
                    "recv_msgs": c.recv_msgs,
                    "recv_bytes": c.recv_bytes,
                    "dropped": dict(c.dropped),
                }
                for kind, c in sorted(self._kinds.items())
            }
