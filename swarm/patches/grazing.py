"""Depth pixels whose surface is seen too obliquely to integrate.

Signed distance is projective (`swarm.patches.backend`): a voxel takes the depth of the pixel it projects into,
measured at that pixel's centre. Where the surface is seen at incidence i (the angle between the ray and the
surface normal), depth changes by about z * pixel_angle * tan(i) across one pixel, so a voxel just behind the
surface can read up to half that in front of it: free. A horizontal camera sees floors and ceilings at grazing
angles (a ceiling 0.9 m above the camera, 7.5 m away: i = 83 degrees, 0.4 m per pixel at 160x120 and 90 degrees
of field of view), and a 0.2 m floor slab seen so from below read as free voxel, then never-seen voxel: the
0.2 m planning cells, half known and none occupied, counted as seen free, and a drone planned through the slab
to the storey above and hit it. Closer views, at smaller incidence, see the voxel behind the surface as
occupied in the same frame that sees the one in front as free.

So pixels seen at more than `max_incidence_deg` are not integrated (depth set to 0, no return), and neither are
pixels whose 4-neighbours lack a return (no normal: the image border, depth edges). The normal is the cross
product of the central differences of the back-projected points: a depth edge gives a grazing normal, so a
surface's silhouette against a far background is dropped too, which also keeps background depth off voxels
just behind a foreground edge.
"""

from __future__ import annotations

import math

import numpy as np


def grazing_mask(depth: np.ndarray, K: np.ndarray, max_incidence_deg: float) -> np.ndarray:
    """(H, W) bool: the pixels with a return, returning neighbours, and incidence <= max_incidence_deg."""
    z = np.asarray(depth, dtype=np.float32)
    h, w = z.shape
    valid = np.isfinite(z) & (z > 0)
    keep = np.zeros((h, w), dtype=bool)
    if h < 3 or w < 3:
        return keep
    u = (np.arange(w, dtype=np.float32) + 0.5 - np.float32(K[0, 2])) / np.float32(K[0, 0])
    v = (np.arange(h, dtype=np.float32) + 0.5 - np.float32(K[1, 2])) / np.float32(K[1, 1])
    zz = np.where(valid, z, 0.0).astype(np.float32)
    points = np.stack([zz * u[None, :], zz * v[:, None], zz], axis=-1)  # camera frame, (H, W, 3)
    du = points[1:-1, 2:] - points[1:-1, :-2]
    dv = points[2:, 1:-1] - points[:-2, 1:-1]
    normal = np.cross(du, dv)
    ray = points[1:-1, 1:-1]
    dot = np.abs(np.einsum("ijk,ijk->ij", normal, ray))
    norms = np.linalg.norm(normal, axis=-1) * np.linalg.norm(ray, axis=-1)
    facing = dot >= np.float32(math.cos(math.radians(max_incidence_deg))) * norms
    inner = valid[1:-1, 1:-1] & valid[1:-1, 2:] & valid[1:-1, :-2] & valid[2:, 1:-1] & valid[:-2, 1:-1]
    keep[1:-1, 1:-1] = inner & facing & (norms > 0)
    return keep


def drop_grazing(depth: np.ndarray, K: np.ndarray, max_incidence_deg: float) -> np.ndarray:
    """`depth` with the pixels `grazing_mask` rejects set to 0 (no return); unchanged at 90 degrees or more."""
    if max_incidence_deg >= 90.0:
        return depth
    return np.where(grazing_mask(depth, K, max_incidence_deg), depth, np.float32(0.0)).astype(np.float32)
