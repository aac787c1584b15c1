"""Marching cubes through Open3D: a `VoxelBlockGrid` rebuilt from fused arrays, then `extract_triangle_mesh`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d

from swarm.patches.backend import tensor
from swarm.patches.lattice import Lattice
from swarm.patches.patch import TsdfArrays

o3c = o3d.core


def extract_mesh(lattice: Lattice, arrays: TsdfArrays, weight_threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """(V,3) float64 world vertices and (F,3) int32 triangles of the zero level set, over voxels whose weight
    exceeds `weight_threshold` (strictly, as Open3D does)."""
    empty = np.zeros((0, 3), dtype=np.float64), np.zeros((0, 3), dtype=np.int32)
    if len(arrays.keys) == 0:
        return empty
    vbg = o3d.t.geometry.VoxelBlockGrid(
        ("tsdf", "weight"),
        (o3c.float32, o3c.float32),
        ((1), (1)),  # type: ignore[arg-type]  # open3d's stub misses the implicit conversion to SizeVector
        lattice.voxel_size,
        lattice.block_resolution,
        len(arrays.keys),
        o3c.Device("CPU:0"),
    )
    hashmap = vbg.hashmap()
    keys = tensor(np.ascontiguousarray(arrays.keys, dtype=np.int32))
    hashmap.activate(keys)
    buf, _ = hashmap.find(keys)
    rows = buf.numpy().astype(np.int64)
    cap = hashmap.capacity()  # read after activate: a rehash reallocates the attribute buffers
    vbg.attribute("tsdf").numpy().reshape(cap, -1)[rows] = arrays.tsdf
    vbg.attribute("weight").numpy().reshape(cap, -1)[rows] = arrays.weight
    try:
        mesh = vbg.extract_triangle_mesh(weight_threshold=float(weight_threshold))
    except RuntimeError:  # Open3D raises instead of returning an empty mesh when no voxel passes
        return empty
    if "positions" not in mesh.vertex or "indices" not in mesh.triangle:
        return empty
    vertices = mesh.vertex.positions.numpy().astype(np.float64) + lattice.origin_array
    return vertices, mesh.triangle.indices.numpy().astype(np.int32)


_EMPTY_PLY = (
    "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty double x\nproperty double y\n"
    "property double z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n"
)


def write_ply(path: str | Path, vertices: np.ndarray, triangles: np.ndarray) -> None:
    if len(vertices) == 0:  # Open3D refuses to write an empty mesh
        Path(path).write_text(_EMPTY_PLY)
        return
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles))
    if not o3d.io.write_triangle_mesh(Path(path), mesh, write_ascii=False):
        raise OSError(f"cannot write mesh to {path}")


def merge_meshes(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """One mesh of several (vertices, triangles) parts, vertices at identical positions merged into one (sorted by
    position). Empties `parts` once concatenated; works on int32 indices: `np.unique(axis=0)` took twice the memory."""
    parts[:] = [(v, t) for v, t in parts if len(v)]
    if not parts:
        return np.zeros((0, 3), dtype=np.float64), np.zeros((0, 3), dtype=np.int32)
    offsets = np.cumsum([0] + [len(v) for v, _ in parts[:-1]])
    vertices = np.concatenate([v for v, _ in parts])
    triangles = np.concatenate([t.astype(np.int32) + np.int32(offset) for (_, t), offset in zip(parts, offsets)])
    parts.clear()
    order = np.lexsort((vertices[:, 2], vertices[:, 1], vertices[:, 0]))
    vertices = vertices[order]
    first = np.ones(len(vertices), dtype=bool)
    first[1:] = np.any(vertices[1:] != vertices[:-1], axis=1)
    index = np.empty(len(vertices), dtype=np.int32)
    index[order] = np.cumsum(first, dtype=np.int32) - 1
    del order
    np.take(index, triangles, out=triangles)
    return vertices[first], triangles
