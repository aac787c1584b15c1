"""A recorded bag as the camera (camera.source = "replay"): a real flight's sensor streams, played back at the
pace they were recorded, through the same `StreamInbox` as a live camera, for hardware-free tests of what a
drone saw. Topics are picked by type when the bag has one of each (`bag_streams`)."""

from __future__ import annotations

import functools
import threading
import time
from pathlib import Path

import numpy as np

from swarm.config import SensorStreamSettings
from swarm.errors import SwarmError
from swarm.sensing.bags import bag_streams
from swarm.sensing.messages import SensorInputError
from swarm.sensing.stream import StreamInbox


class BagReplaySource(StreamInbox):
    def __init__(self, bag: Path, settings: SensorStreamSettings, mount: np.ndarray, speed: float = 1.0) -> None:
        super().__init__(settings, mount)
        self.bag, self.speed = bag, speed
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.finished = threading.Event()  # the whole bag was played

    def start(self) -> None:
        """Check the bag (SwarmError, one line, when it cannot be played) and start playing it."""
        try:
            next(iter(bag_streams([self.bag])), None)  # opens it and picks its topics: raises on a bad bag
        except SensorInputError as exc:
            raise SwarmError(f"camera.replay_bag: {exc}") from None
        self._thread = threading.Thread(target=self._play, name="replay", daemon=True)
        self._thread.start()

    def _play(self) -> None:
        handlers = {kind: handler for kind, (_, _, handler) in zip(("info", "pose", "depth"), self.topics())}
        started, first = time.monotonic(), None
        for kind, msgtype, raw, t_ns in bag_streams([self.bag]):
            first = t_ns if first is None else first
            due = started + (t_ns - first) / 1e9 / self.speed
            if self._stop.wait(max(0.0, due - time.monotonic())):
                return
            if kind == "pose":
                self.deliver(kind, msgtype, functools.partial(self.frames.on_pose, msgtype=msgtype), raw)
            else:
                self.deliver(kind, msgtype, handlers[kind], raw)
        self.finished.set()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
