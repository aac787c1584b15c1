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
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from swarm.config import Vec3

_SLOPE_EPS = 1e-9  # a ray just tangent to a sphere stays in its silhouette's box
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


@lru_cache(maxsize=4)
def _cached_rays(focal_centre: tuple[float, float, float, float], height: int, width: int) -> np.ndarray:
    """`pixel_rays` of a camera (fx, fy, cx, cy) of one image size, made once: a stream's frames share them."""
    fx, fy, cx, cy = focal_centre
    rays = pixel_rays(np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), height, width)
    rays.flags.writeable = False
    return rays


def sphere_depth(
    rays: np.ndarray, T_world_cam: np.ndarray, centres: Sequence[Sequence[float]] | np.ndarray, radius: float
) -> np.ndarray:
    """(H, W) z-depth at which each ray first meets one of the spheres (in front of the camera); inf where none.
    `rays` as `pixel_rays` gives them (z = 1; x grows along a row, y down a column).

    Each sphere is tested only against the rays of the pixel box its silhouette can cover (`_silhouette`), and
    not at all when it lies wholly behind the camera: the same depths as testing every ray, for a few dozen
    pixels where a far peer covers them, instead of the whole image per peer."""
    out = np.full(rays.shape[:2], np.inf)
    centres_ = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    if len(centres_) == 0:
        return out
    R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
    in_camera = (centres_ - t) @ R  # world -> camera frame: R^T (c - t), row-wise
    xs, ys = rays[0, :, 0], rays[:, 0, 1]
    for c in in_camera:
        if c[2] + radius <= 0.0:
            continue  # wholly behind the camera: no ray meets it at a positive depth
        cols, rows = _silhouette(xs, c[0], c[2], radius), _silhouette(ys, c[1], c[2], radius)
        if cols is None or rows is None:
            continue
        box = rays[rows, cols]
        a = np.einsum("hwk,hwk->hw", box, box)
        b = box @ c
        disc = b * b - a * (c @ c - radius * radius)
        hit = disc >= 0.0
        near = np.where(hit, (b - np.sqrt(np.where(hit, disc, 0.0))) / a, np.inf)
        far = np.where(hit, (b + np.sqrt(np.where(hit, disc, 0.0))) / a, np.inf)
        first = np.where(near > 0.0, near, np.where(far > 0.0, 0.0, np.inf))  # camera inside: everything hidden
        np.minimum(out[rows, cols], first, out=out[rows, cols])
    return out


def _silhouette(slopes: np.ndarray, across: float, depth: float, radius: float) -> slice | None:
    """The pixels (a slice of `slopes`, the rays' x/z or y/z, ascending) whose rays can meet a sphere of `radius`
    centred `across` to the side and `depth` ahead; None if none can; every pixel when the sphere reaches the
    camera's plane. A ray meets the sphere only if its projection on the plane of that axis and the optical axis
    meets the sphere's disk there: its slope s lies between the two tangents, the roots of
    s^2 (depth^2 - r^2) - 2 s across depth + across^2 - r^2 = 0."""
    if depth <= radius:
        return slice(None)
    spread = radius * np.sqrt(across * across + depth * depth - radius * radius)
    scale = depth * depth - radius * radius
    lo, hi = (across * depth - spread) / scale - _SLOPE_EPS, (across * depth + spread) / scale + _SLOPE_EPS
    first, last = np.searchsorted(slopes, lo, side="left"), np.searchsorted(slopes, hi, side="right")
    return slice(int(first), int(last)) if last > first else None


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
    k = np.asarray(K, dtype=np.float64)
    rays = _cached_rays((float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2])), *depth.shape)
    hit = sphere_depth(rays, T_world_cam, peers, radius)
    masked = np.isfinite(hit) & ((depth <= 0) | (hit <= depth + radius))
    if not masked.any():
        return depth, 0
    out = depth.copy()
    out[masked] = 0.0
    return out, int(masked.sum())
