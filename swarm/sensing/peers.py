"""Other drones in a depth image: where the camera's pixel rays meet a sphere round each of them.

A real camera sees the other drones of the swarm. Mapped, they would leave phantom obstacles along every path
they fly, so the agent masks the pixels whose rays meet a sphere of `camera.peer_mask_m` round each peer's
position before it integrates a frame: those pixels count as invalid (no surface, no free space carved). A
heartbeat is up to a period old when it arrives and a frame is integrated a little after it was taken, so each
peer is placed where its last heartbeat's position and velocity put it at the frame's stamp (`PeerSighting.at`).
The simulated camera uses the same geometry the other way round, to draw each drone into the
images of the others (a sphere of the drone's radius).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from swarm.config import Vec3

PREDICT_MAX_S = 1.0  # extrapolate a heartbeat at most this far: beyond that the peer is wherever it last said


class PeerSighting(NamedTuple):
    """A peer's last heartbeat: where it was and how fast it moved, at `heard` (wall-clock seconds, the clock of
    the sensor stamps)."""

    position: Vec3
    velocity: Vec3
    heard: float

    def at(self, t: float) -> np.ndarray:
        """Where this heartbeat puts the peer at wall-clock time `t` (dead reckoning within PREDICT_MAX_S)."""
        dt = min(max(t - self.heard, -PREDICT_MAX_S), PREDICT_MAX_S)
        return np.asarray(self.position, dtype=np.float64) + dt * np.asarray(self.velocity, dtype=np.float64)


def pixel_rays(K: np.ndarray, height: int, width: int) -> np.ndarray:
    """(H, W, 3) camera-frame rays through the pixel centres (u + 0.5, v + 0.5), with z = 1 (t is z-depth)."""
    u = (np.arange(width) + 0.5 - K[0, 2]) / K[0, 0]
    v = (np.arange(height) + 0.5 - K[1, 2]) / K[1, 1]
    rays = np.ones((height, width, 3))
    rays[..., 0] = u[None, :]
    rays[..., 1] = v[:, None]
    return rays


def sphere_depth(
    rays: np.ndarray, T_world_cam: np.ndarray, centres: Sequence[Sequence[float]] | np.ndarray, radius: float
) -> np.ndarray:
    """(H, W) z-depth at which each ray first meets one of the spheres (in front of the camera); inf where none."""
    out = np.full(rays.shape[:2], np.inf)
    centres_ = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    if len(centres_) == 0:
        return out
    R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
    in_camera = (centres_ - t) @ R  # world -> camera frame: R^T (c - t), row-wise
    a = np.einsum("hwk,hwk->hw", rays, rays)
    for c in in_camera:
        b = rays @ c
        disc = b * b - a * (c @ c - radius * radius)
        hit = disc >= 0.0
        near = np.where(hit, (b - np.sqrt(np.where(hit, disc, 0.0))) / a, np.inf)
        far = np.where(hit, (b + np.sqrt(np.where(hit, disc, 0.0))) / a, np.inf)
        first = np.where(near > 0.0, near, np.where(far > 0.0, 0.0, np.inf))  # camera inside: everything hidden
        out = np.minimum(out, first)
    return out


def mask_peers(
    depth: np.ndarray,
    K: np.ndarray,
    T_world_cam: np.ndarray,
    peers: Sequence[Sequence[float]] | np.ndarray,
    radius: float,
) -> tuple[np.ndarray, int]:
    """`depth` with 0 in every pixel whose ray meets a sphere of `radius` round a peer before its surface (or
    at all, where the pixel had no surface); and how many pixels that was. `depth` is not modified."""
    if len(peers) == 0:
        return depth, 0
    hit = sphere_depth(pixel_rays(K, *depth.shape), T_world_cam, peers, radius)
    masked = np.isfinite(hit) & ((depth <= 0) | (hit <= depth + radius))
    if not masked.any():
        return depth, 0
    out = depth.copy()
    out[masked] = 0.0
    return out, int(masked.sum())
