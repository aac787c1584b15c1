"""An analytic scene for mapping tests: the inside of an axis-aligned box room, rendered exactly."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

ROOM_LO = np.array([0.0, 0.0, 0.0])
ROOM_HI = np.array([6.0, 5.0, 3.0])
CENTRE = np.array([3.0, 2.5, 1.5])
MAX_RANGE = 8.0


def intrinsics(width: int = 160, height: int = 120, hfov_deg: float = 90.0) -> np.ndarray:
    f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


def pose(position: np.ndarray, yaw_deg: float, pitch_deg: float = 0.0) -> np.ndarray:
    """Camera-to-world (camera x right, y down, z forward), looking along yaw, pitched down by pitch_deg."""
    yaw, pitch = math.radians(yaw_deg), math.radians(pitch_deg)
    forward = np.array([math.cos(yaw) * math.cos(pitch), math.sin(yaw) * math.cos(pitch), -math.sin(pitch)])
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = right, np.cross(forward, right), forward
    T[:3, 3] = position
    return T


def render_room(
    K: np.ndarray, T: np.ndarray, shape: tuple[int, int] = (120, 160), max_range: float = MAX_RANGE
) -> np.ndarray:
    """z-depth (float32, 0 = no return) of the room's inner walls seen from T (the camera must be inside)."""
    h, w = shape
    v, u = np.mgrid[0:h, 0:w]
    cam = np.stack([(u + 0.5 - K[0, 2]) / K[0, 0], (v + 0.5 - K[1, 2]) / K[1, 1], np.ones((h, w))], axis=-1)
    dirs = cam @ T[:3, :3].T
    centre = T[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_hi = np.where(dirs > 0, (ROOM_HI - centre) / dirs, np.inf)
        t_lo = np.where(dirs < 0, (ROOM_LO - centre) / dirs, np.inf)
    depth = np.minimum(t_hi, t_lo).min(axis=-1)  # camera-z == 1 rays: the ray parameter is the z-depth
    depth[~(depth <= max_range)] = 0.0
    return depth.astype(np.float32)


@dataclass(frozen=True)
class Frame:
    depth: np.ndarray
    K: np.ndarray
    T: np.ndarray
    t: float


def rotate_in_place(
    position: np.ndarray = CENTRE, yaws: int = 12, pitches: tuple[float, ...] = (-40.0, 0.0, 40.0)
) -> list[Frame]:
    K = intrinsics()
    frames = []
    for i in range(yaws):
        for pitch in pitches:
            T = pose(position, 360.0 * i / yaws, pitch)
            frames.append(Frame(render_room(K, T), K, T, 0.1 * len(frames)))
    return frames


def distance_to_walls(points: np.ndarray) -> np.ndarray:
    """Distance of points to the nearest of the room's six wall planes."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return np.minimum(np.abs(p - ROOM_LO), np.abs(p - ROOM_HI)).min(axis=1)
