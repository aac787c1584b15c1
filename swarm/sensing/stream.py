"""Camera frames from a stream of ROS 2 messages: depth images, camera info and poses, in any order.

`FrameAssembler` is sans-I/O (as `PullScheduler` is for patch sync): whatever carries the messages (rclpy, a
Zenoh subscription, a bag) hands it their CDR bytes or decoded messages, and it hands back `DepthFrame`s with the
camera pose at each image's stamp. An image that arrives before the pose sample after its stamp waits for it,
while the images behind it span at most `max_wait_s` of stamps (a time, so the same at any camera rate; a stalled
pose stream holds at most that much of the camera's stream) and at most `max_pending` images (memory). Every
message it cannot use is counted under its reason (`dropped`) and never reaches the map: a malformed message, an
image in an encoding that is not depth (none of 16UC1, mono16, 32FC1), an image before any camera info, an image
whose size differs from the camera info's, a stamp with no pose (stale, too new, across a gap, or none in time).
"""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from swarm.config import SensorStreamSettings
from swarm.sensing.bags import BagRecorder
from swarm.sensing.frames import DepthFrame, camera_to_world, pixel_centre_intrinsics
from swarm.sensing.messages import (
    CAMERA_INFO,
    IMAGE,
    ODOMETRY,
    POSE_STAMPED,
    Intrinsics,
    Pose,
    SensorInputError,
    UnknownEncodingError,
    depth_of,
    deserialize,
    intrinsics_of,
    pose_of,
)
from swarm.sensing.poses import Miss, PoseBuffer


class FrameAssembler:
    def __init__(
        self, mount: np.ndarray, poses: PoseBuffer | None = None, max_wait_s: float = 1.0, max_pending: int = 64
    ) -> None:
        if not (max_wait_s > 0 and max_pending >= 1):
            raise ValueError(f"bad frame assembler: max_wait_s {max_wait_s}, max_pending {max_pending}")
        self.mount = np.asarray(mount, dtype=np.float64)
        self.poses = poses if poses is not None else PoseBuffer()  # an empty buffer is falsy
        self.max_wait_s = max_wait_s
        self.max_pending = max_pending
        self.intrinsics: Intrinsics | None = None
        self._K: np.ndarray | None = None
        self._pending: deque[tuple[float, np.ndarray]] = deque()
        self._ready: list[DepthFrame] = []
        self.frames = 0
        self.dropped: Counter[str] = Counter()

    # -- input ---------------------------------------------------------------------------------------------

    def on_camera_info(self, message: Any) -> None:
        try:
            self.intrinsics = intrinsics_of(_decoded(message, CAMERA_INFO))
        except SensorInputError:
            self.dropped["bad camera info"] += 1
            return
        self._K = pixel_centre_intrinsics(self.intrinsics)

    def on_pose(self, message: Any, msgtype: str | None = None) -> None:
        """A pose message (Odometry or PoseStamped; `msgtype` needed only for CDR bytes), or a `Pose`."""
        try:
            pose = message if isinstance(message, Pose) else pose_of(_decoded(message, msgtype))
        except SensorInputError:
            self.dropped["bad pose"] += 1
            return
        if not self.poses.add(pose):
            self.dropped["pose out of order"] += 1
            return
        self._resolve()

    def on_image(self, message: Any) -> None:
        try:
            stamp, depth = depth_of(_decoded(message, IMAGE))
        except UnknownEncodingError:
            self.dropped["unknown encoding"] += 1
            return
        except SensorInputError:
            self.dropped["bad image"] += 1
            return
        if self.intrinsics is None:
            self.dropped["image before camera info"] += 1
            return
        if depth.shape != (self.intrinsics.height, self.intrinsics.width):
            self.dropped["image size differs from camera info"] += 1
            return
        self._pending.append((stamp, depth))
        while len(self._pending) > self.max_pending or stamp - self._pending[0][0] > self.max_wait_s:
            self._pending.popleft()
            self.dropped["no pose in time"] += 1
        self._resolve()

    # -- output --------------------------------------------------------------------------------------------

    def take(self) -> list[DepthFrame]:
        """The frames assembled since the last call, oldest first."""
        ready, self._ready = self._ready, []
        return ready

    def _resolve(self) -> None:
        """Turn the pending images whose pose is known into frames; drop those that will never have one."""
        while self._pending:
            stamp, depth = self._pending[0]
            pose = self.poses.at(stamp)
            if pose is Miss.FUTURE or pose is Miss.EMPTY:
                return  # the pose after this stamp may still come (images are in stamp order: so for the rest)
            self._pending.popleft()
            if isinstance(pose, Miss):
                self.dropped[f"pose {pose.name.lower()}"] += 1
                continue
            assert self._K is not None
            self._ready.append(DepthFrame(self.frames, stamp, depth, self._K.copy(), camera_to_world(pose, self.mount)))
            self.frames += 1


POSE_TYPES = {"odometry": ODOMETRY, "pose_stamped": POSE_STAMPED}


class StreamInbox:
    """What every live source shares: raw CDR messages in from the transport's threads, through one
    `FrameAssembler` under a lock, recorded to a bag when asked, and the newest frame out to the mapping thread
    (`wait_frame`), counting the frames it never took."""

    def __init__(self, settings: SensorStreamSettings, mount: np.ndarray, record: Path | None = None) -> None:
        self.settings = settings
        self.record = record
        self.recorder: BagRecorder | None = None
        self.frames = FrameAssembler(
            mount,
            PoseBuffer(max_gap_s=settings.max_gap_s, max_hold_s=settings.max_hold_s),
            max_wait_s=settings.max_pose_wait_s,
        )
        self._lock = threading.Lock()
        self._new = threading.Condition(self._lock)
        self._latest: DepthFrame | None = None
        self.not_taken = 0  # frames replaced by a newer one before the mapping thread took them

    def open_recording(self) -> None:
        if self.record is not None:
            self.recorder = BagRecorder(self.record)

    def topics(self) -> list[tuple[str, str, Callable[[bytes], None]]]:
        """(topic, message type, handler of its raw CDR) of the three subscriptions."""
        s = self.settings
        pose_type = POSE_TYPES[s.pose_type]
        return [
            (s.info_topic, CAMERA_INFO, self.frames.on_camera_info),
            (s.pose_topic, pose_type, lambda raw: self.frames.on_pose(raw, pose_type)),
            (s.depth_topic, IMAGE, self.frames.on_image),
        ]

    def deliver(self, topic: str, msgtype: str, handler: Callable[[bytes], None], raw: bytes) -> None:
        # Recorded under the lock, so the bag holds the messages in the order the assembler took them (the
        # transport calls from several threads): a replay then makes exactly the frames this run made.
        with self._new:
            if self.recorder is not None:
                self.recorder.write(topic, msgtype, time.time_ns(), raw)
            handler(raw)
            ready = self.frames.take()
            if ready:
                self.not_taken += len(ready) - 1 + (self._latest is not None)
                self._latest = ready[-1]
                self._new.notify_all()

    def wait_frame(self, timeout_s: float) -> DepthFrame | None:
        """The newest frame not taken yet, waiting up to `timeout_s` for one; None when none came."""
        with self._new:
            if self._latest is None:
                self._new.wait_for(lambda: self._latest is not None, timeout_s)
            frame, self._latest = self._latest, None
            return frame

    def counters(self) -> dict[str, int]:
        with self._lock:
            return {"frames": self.frames.frames, "not_taken": self.not_taken, **dict(self.frames.dropped)}

    def close_recording(self) -> None:
        if self.recorder is not None:
            self.recorder.close()


def _decoded(message: Any, msgtype: str | None) -> Any:
    if isinstance(message, (bytes, bytearray, memoryview)):
        if msgtype is None:
            raise SensorInputError("CDR bytes without their message type")
        return deserialize(message, msgtype)
    return message
