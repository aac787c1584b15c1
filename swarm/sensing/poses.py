"""The vehicle's recent poses, and its pose at an image's timestamp.

A camera and the autopilot (or a VIO) stamp their messages on one clock but publish them at different rates and
latencies: an image is usually stamped between two pose samples, and often arrives before the later one. The
pose at the image's stamp is interpolated between the samples that bracket it (position linearly, attitude by
slerp), provided they are at most `max_gap_s` apart; a stamp after the newest sample is held to it for at most
`max_hold_s`. Anything else is refused with the reason, which the caller counts: a frame mapped at the wrong pose
corrupts the map for good, a frame dropped costs a tenth of a second of view.
"""

from __future__ import annotations

import bisect
from collections import deque
from enum import Enum

import numpy as np

from swarm.sensing.messages import Pose


class Miss(str, Enum):
    """Why no pose was found for a stamp."""

    EMPTY = "no pose yet"
    EARLY = "older than the first pose (the stream was starting)"
    STALE = "older than every kept pose"
    FUTURE = "newer than the newest pose by more than max_hold_s"
    GAP = "between poses further apart than max_gap_s"


class PoseBuffer:
    def __init__(self, capacity: int = 512, max_gap_s: float = 0.25, max_hold_s: float = 0.05) -> None:
        if capacity < 2 or not (max_gap_s > 0 and max_hold_s >= 0):
            raise ValueError(f"bad pose buffer: capacity {capacity}, max_gap_s {max_gap_s}, max_hold_s {max_hold_s}")
        self.max_gap_s, self.max_hold_s = max_gap_s, max_hold_s
        self._poses: deque[Pose] = deque(maxlen=capacity)
        self._stamps: deque[float] = deque(maxlen=capacity)
        self.out_of_order = 0  # samples older than the newest (dropped: they would break the ordering)
        self.evicted = False  # a sample fell out of the full buffer: the oldest kept is no longer the first

    def __len__(self) -> int:
        return len(self._poses)

    def add(self, pose: Pose) -> bool:
        """Keep `pose`; False (and counted) when it is not newer than the newest kept."""
        if self._stamps and pose.t <= self._stamps[-1]:
            self.out_of_order += 1
            return False
        self.evicted = self.evicted or len(self._poses) == self._poses.maxlen
        self._poses.append(pose)
        self._stamps.append(pose.t)
        return True

    def at(self, t: float) -> Pose | Miss:
        if not self._poses:
            return Miss.EMPTY
        newest = self._poses[-1]
        if t >= newest.t:
            return Pose(t, newest.position, newest.orientation) if t - newest.t <= self.max_hold_s else Miss.FUTURE
        i = bisect.bisect_right(self._stamps, t)  # deque supports indexing: O(n) worst, n <= capacity
        if i == 0:
            return Miss.STALE if self.evicted else Miss.EARLY
        before, after = self._poses[i - 1], self._poses[i]
        if after.t - before.t > self.max_gap_s:
            return Miss.GAP
        s = (t - before.t) / (after.t - before.t)
        return Pose(
            t, before.position + s * (after.position - before.position), slerp(before.orientation, after.orientation, s)
        )


def slerp(q0: np.ndarray, q1: np.ndarray, s: float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (x, y, z, w), the short way round."""
    q0, q1 = np.asarray(q0, dtype=np.float64), np.asarray(q1, dtype=np.float64)
    dot = float(np.dot(q0, q1))
    if dot < 0.0:
        q1, dot = -q1, -dot
    if dot > 0.9995:  # nearly the same attitude: linear, then renormalised (slerp's sine ratio is ill-conditioned)
        q = q0 + s * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(dot)
    return (np.sin((1 - s) * theta) * q0 + np.sin(s * theta) * q1) / np.sin(theta)
