"""Integration and the fused map on the analytic box room: free-space carving, classification, mesh accuracy,
the coarse occupancy grid."""

import hashlib
from collections import Counter

import numpy as np
import pytest

from swarm.patches.backend import VoxelBlockGridBackend, dropoff_weight
from swarm.patches.carving import frame_blocks
from swarm.patches.fused import FREE, OCCUPIED, UNKNOWN, FusedMap
from swarm.patches.lattice import Lattice
from swarm.patches.patch import FrameSpan, Patch, PatchId, VoxelBlocks, quantise
from tests.patches.scene import (
    CENTRE,
    MAX_RANGE,
    ROOM_HI,
    ROOM_LO,
    distance_to_walls,
    intrinsics,
    pose,
    render_room,
    rotate_in_place,
)

BOUNDS = (ROOM_LO - 1.0, ROOM_HI + 1.0)


def map_of(frames, lattice: Lattice) -> FusedMap:
    backend = VoxelBlockGridBackend(lattice)
    for f in frames:
        backend.integrate(f.depth, f.K, f.T, MAX_RANGE)
    fused = FusedMap(lattice, BOUNDS)
    blocks = quantise(backend.extract(), lattice)
    fused.add(Patch.seal(PatchId(1, 0, 0), lattice, FrameSpan(0, len(frames) - 1, 0.0, 1.0), frames[0].T, blocks))
    return fused


@pytest.fixture(scope="module")
def room_map() -> FusedMap:
    return map_of(rotate_in_place(), Lattice(0.1, 8, 4.0))


def test_frame_blocks_hold_the_surface_band_and_the_rays() -> None:
    lattice = Lattice(0.1, 8, 4.0)
    K, T = intrinsics(), pose(CENTRE, 0.0)
    depth = render_room(K, T)
    keys = {tuple(k) for k in frame_blocks(depth, K, T, lattice, MAX_RANGE)}
    wall_x = ROOM_HI[0]  # looking along +x at the wall x = 6
    for d in np.arange(0.0, wall_x - CENTRE[0] + lattice.truncation_m, 0.05):
        assert tuple(lattice.point_to_block(CENTRE + [d, 0.0, 0.0])[0]) in keys
    for dy in (-0.4, 0.0, 0.4):  # on the wall and +- truncation around it
        for dx in (-0.4, 0.0, 0.39):
            assert tuple(lattice.point_to_block([wall_x + dx, 2.5 + dy, 1.5])[0]) in keys
    assert tuple(lattice.point_to_block([wall_x + 1.5, 2.5, 1.5])[0]) not in keys  # beyond the band
    assert len(frame_blocks(np.zeros_like(depth), K, T, lattice, MAX_RANGE)) == 0


def test_free_space_is_carved_and_behind_the_wall_stays_unknown(room_map: FusedMap) -> None:
    rng = np.random.default_rng(0)
    air = rng.uniform(ROOM_LO + 0.5, ROOM_HI - 0.5, size=(2000, 3))
    seen_air = air[np.abs(air[:, 0] - CENTRE[0]) + np.abs(air[:, 1] - CENTRE[1]) > 0.8]  # not straight below/above
    assert np.mean(room_map.state_at(seen_air) == FREE) > 0.99
    behind = np.array([[ROOM_HI[0] + 0.8, 2.5, 1.5], [ROOM_LO[0] - 0.8, 2.5, 1.5], [3.0, ROOM_HI[1] + 0.8, 1.5]])
    assert np.all(room_map.state_at(behind) == UNKNOWN)
    in_wall = np.array([[ROOM_HI[0] + 0.15, 2.5, 1.5], [3.0, ROOM_LO[1] - 0.15, 1.5], [2.0, 2.0, ROOM_LO[2] - 0.15]])
    assert np.all(room_map.state_at(in_wall) == OCCUPIED)
    assert 0.0 < room_map.known_fraction < 1.0
    assert room_map.known_count <= room_map.voxel_count


def test_mesh_vertices_lie_within_a_voxel_of_the_walls(room_map: FusedMap, tmp_path) -> None:
    vertices, triangles = room_map.mesh()
    assert len(vertices) > 1000 and len(triangles) > 1000
    assert distance_to_walls(vertices).max() <= room_map.lattice.voxel_size
    n_v, n_t = room_map.write_mesh(tmp_path / "room.ply")
    assert (n_v, n_t) == (len(vertices), len(triangles))
    assert (tmp_path / "room.ply").read_bytes().startswith(b"ply")


def _triangle_set(vertices: np.ndarray, triangles: np.ndarray) -> Counter[tuple[float, ...]]:
    """Each non-degenerate triangle as its corners' positions, rotated to start at the smallest corner, counted."""
    out: Counter[tuple[float, ...]] = Counter()
    for corners in vertices[triangles]:
        rows = [tuple(c) for c in corners]
        if len(set(rows)) < 3:
            continue
        i = rows.index(min(rows))
        out[sum(rows[i:] + rows[:i], ())] += 1
    return out


@pytest.mark.parametrize("tile_blocks", [1, 7, 48])
def test_the_mesh_made_in_tiles_is_the_mesh_made_whole(room_map: FusedMap, monkeypatch, tile_blocks: int) -> None:
    monkeypatch.setattr("swarm.patches.fused.MESH_TILE_BLOCKS", 10**9)
    whole = room_map.mesh()
    monkeypatch.setattr("swarm.patches.fused.MESH_TILE_BLOCKS", tile_blocks)
    tiled = room_map.mesh()
    assert len(room_map.block_keys()) >= 10 * tile_blocks  # many seams
    assert len(tiled[0]) == len(np.unique(tiled[0], axis=0))  # seam vertices merged
    assert np.array_equal(np.unique(whole[0], axis=0), tiled[0])
    assert _triangle_set(*whole) == _triangle_set(*tiled)
    some = room_map.block_keys()[::3]
    monkeypatch.setattr("swarm.patches.fused.MESH_TILE_BLOCKS", 10**9)
    whole_within = room_map.mesh(within=some)
    monkeypatch.setattr("swarm.patches.fused.MESH_TILE_BLOCKS", tile_blocks)
    assert _triangle_set(*whole_within) == _triangle_set(*room_map.mesh(within=some))


def test_occupancy_grid_marks_walls_occupied_and_the_room_free(room_map: FusedMap) -> None:
    origin, states = room_map.occupancy_grid(0.2, ROOM_LO - 1.0, ROOM_HI + 1.0)
    assert states.dtype == np.uint8 and states.shape == (40, 35, 25)
    centres = origin + (np.indices(states.shape).reshape(3, -1).T + 0.5) * 0.2
    s = states.ravel()
    below_camera = np.hypot(centres[:, 0] - CENTRE[0], centres[:, 1] - CENTRE[1]) < 0.6
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        away_from_edges = np.all(
            (centres[:, others] > ROOM_LO[others] + 0.2) & (centres[:, others] < ROOM_HI[others] - 0.2), axis=1
        )
        for plane, outward in ((ROOM_LO[axis], -1.0), (ROOM_HI[axis], 1.0)):
            # the cells just behind the surface (the grid's cell edges lie on the walls)
            on_plane = (np.abs(centres[:, axis] - (plane + 0.1 * outward)) < 0.05) & away_from_edges & ~below_camera
            assert on_plane.sum() > 50
            assert np.all(s[on_plane] == OCCUPIED), (axis, plane)
    interior = np.all((centres > ROOM_LO + 0.5) & (centres < ROOM_HI - 0.5), axis=1)
    interior &= np.abs(centres[:, 0] - CENTRE[0]) + np.abs(centres[:, 1] - CENTRE[1]) > 0.8
    assert np.mean(s[interior] == FREE) > 0.97
    assert not np.any(s[interior] == OCCUPIED)
    # projective sdf: the band reaches truncation / cos(pixel angle) <= 0.4 / cos(51 deg) = 0.64 m behind walls
    beyond_truncation = np.any((centres < ROOM_LO - 0.75) | (centres > ROOM_HI + 0.75), axis=1)
    assert np.all(s[beyond_truncation] == UNKNOWN)


def test_inverse_square_weights_fall_with_distance() -> None:
    lattice = Lattice(0.1, 8, 4.0, weight_law="inverse_square")
    backend = VoxelBlockGridBackend(lattice)
    K, T = intrinsics(), pose(CENTRE, 0.0)
    backend.integrate(render_room(K, T), K, T, MAX_RANGE)
    backend.integrate(render_room(K, T), K, T, MAX_RANGE)  # two frames: the running average is exercised
    fused = FusedMap(lattice, BOUNDS)
    fused.add(Patch.seal(PatchId(1, 0, 0), lattice, FrameSpan(0, 1, 0.0, 0.1), T, quantise(backend.extract(), lattice)))
    arrays = fused.arrays()
    points = lattice.voxel_to_point(lattice.block_voxel_indices(arrays.keys).reshape(-1, 3))
    weight, tsdf = arrays.weight.ravel(), arrays.tsdf.ravel()
    on_axis = (np.abs(points[:, 1] - 2.5) < 0.01) & (np.abs(points[:, 2] - 1.5) < 0.01) & (weight > 0)
    d = np.linalg.norm(points[on_axis] - CENTRE, axis=1)
    expected = 2.0 / np.maximum(d, 0.3) ** 2
    assert np.allclose(weight[on_axis], expected, rtol=0.01, atol=2 / 256)
    free_part = on_axis.copy()
    free_part[on_axis] = d < 2.5
    assert np.allclose(tsdf[free_part], 1.0, atol=1 / 127)


def test_an_empty_map_answers_unknown_everywhere(tmp_path) -> None:
    fused = FusedMap(Lattice(0.1, 8, 4.0), BOUNDS)
    assert fused.voxel_count == 0 and fused.known_fraction == 0.0 and fused.block_count == 0
    assert fused.state_at(np.zeros((0, 3))).shape == (0,)
    assert np.all(fused.state_at([[1.0, 1.0, 1.0], [100.0, 0.0, 0.0]]) == UNKNOWN)
    _, states = fused.occupancy_grid(0.2)
    assert not states.any()
    vertices, triangles = fused.mesh()
    assert vertices.shape == (0, 3) and triangles.shape == (0, 3)
    assert fused.write_mesh(tmp_path / "empty.ply") == (0, 0)
    assert fused.digest() == FusedMap(Lattice(0.1, 8, 4.0), BOUNDS).digest()


def test_the_dropoff_weight_is_one_down_to_a_voxel_behind_the_surface_then_falls_to_zero() -> None:
    tsdf = np.array([1.0, 0.0, -0.25, -0.5, -0.75, -1.0], dtype=np.float32)  # truncation 4 voxels: one is 0.25
    np.testing.assert_allclose(dropoff_weight(tsdf, 4.0), [1.0, 1.0, 1.0, 2 / 3, 1 / 3, 0.0], atol=1e-6)
    np.testing.assert_allclose(dropoff_weight(tsdf, 1.0), np.ones(6))  # one voxel of truncation: nothing to drop


def test_dropoff_weights_fall_behind_the_surface_and_leave_the_free_space_whole() -> None:
    lattice = Lattice(0.1, 8, 4.0, weight_law="dropoff")
    backend = VoxelBlockGridBackend(lattice)
    K, T = intrinsics(), pose(CENTRE, 0.0)  # the wall x = 6 straight ahead, 3 m away
    for _ in range(2):
        backend.integrate(render_room(K, T), K, T, MAX_RANGE)
    arrays = backend.extract()
    points = lattice.voxel_to_point(lattice.block_voxel_indices(arrays.keys).reshape(-1, 3))
    weight, tsdf = arrays.weight.ravel(), arrays.tsdf.ravel()
    assert np.all(np.isfinite(tsdf))
    on_axis = (np.abs(points[:, 1] - 2.5) < 0.01) & (np.abs(points[:, 2] - 1.5) < 0.01)
    x, w = points[on_axis, 0], weight[on_axis]
    np.testing.assert_allclose(w[(x > 3.5) & (x <= 6.1)], 2.0, rtol=1e-5)  # free space, the wall's face, 1 voxel
    behind = {round(float(a), 1): float(b) for a, b in zip(x, w) if a > 6.15 and b > 0}
    np.testing.assert_allclose([behind[6.2], behind[6.3]], [2 * 2 / 3, 2 * 1 / 3], rtol=1e-4)
    assert 6.4 not in behind  # the truncation distance: weight 0, not observed


def test_an_obstacle_counts_as_soon_as_it_is_seen_and_free_space_once_it_is_known() -> None:
    # Under the drop-off law a guess behind a surface weighs less than the known threshold: it must still be an
    # obstacle (a thin wall seen only edge-on is nothing but such guesses), while free space needs the threshold.
    lattice = Lattice(0.1, 8, 4.0, weight_law="dropoff")
    r3 = lattice.voxels_per_block
    keys = np.array([[0, 0, 0]], dtype=np.int32)
    weight = np.zeros((1, r3), dtype=np.uint16)
    tsdf = np.zeros((1, r3), dtype=np.int8)
    weight[0, :4] = (1, 1, 16, 16)  # 1/16 and 1 (the known threshold) in units of 1/16
    tsdf[0, :4] = (-60, 60, -60, 60)
    fused = FusedMap(lattice, ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0)))
    blocks = VoxelBlocks(keys, tsdf, weight)
    fused.add(Patch.seal(PatchId(1, 0, 0), lattice, FrameSpan(0, 0, 0.0, 0.0), np.eye(4), blocks))
    points = lattice.voxel_to_point(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [4, 0, 0]]))
    assert fused.state_at(points).tolist() == [OCCUPIED, UNKNOWN, OCCUPIED, FREE, UNKNOWN]
    _, voxels = fused.occupancy_grid(0.1, (-0.05, -0.05, -0.05), (0.45, 0.05, 0.05))
    assert voxels[:, 0, 0].tolist() == [OCCUPIED, UNKNOWN, OCCUPIED, FREE, UNKNOWN]


def test_resident_bytes_count_the_block_rows_in_use_and_the_kept_grids() -> None:
    lattice = Lattice(0.1, 8, 4.0)
    room_map = map_of(rotate_in_place()[:4], lattice)  # its own: no occupancy grid kept yet
    empty = FusedMap(lattice, BOUNDS)
    assert empty.resident_bytes == empty._grid.nbytes  # nothing held but the block index
    row = 3 * 4 + 2 * 4 * lattice.voxels_per_block + 8
    assert room_map.resident_bytes >= room_map.block_count * row
    before = room_map.resident_bytes
    room_map.occupancy_grid(0.2, ROOM_LO - 1.0, ROOM_HI + 1.0)  # a kept grid
    assert room_map.resident_bytes > before
    backend = VoxelBlockGridBackend(lattice)
    assert backend.resident_bytes >= 1024 * lattice.voxels_per_block * 8  # the capacity, written at creation


def test_passes_over_the_map_in_row_chunks_give_what_one_pass_gives(room_map: FusedMap, monkeypatch) -> None:
    monkeypatch.setattr("swarm.patches.fused.ROW_CHUNK", 10**9)
    digest, raw = room_map.digest(), room_map.wire_raw()
    fresh = map_of(rotate_in_place(), room_map.lattice)  # no kept grid: computed whole below, then in chunks
    whole = [fresh.occupancy_grid(res, ROOM_LO - 1.0, ROOM_HI + 1.0)[1] for res in (0.1, 0.2)]
    monkeypatch.setattr("swarm.patches.fused.ROW_CHUNK", 7)
    assert len(room_map.block_keys()) > 10 * 7
    assert room_map.digest() == digest and room_map.wire_raw() == raw
    chunked = map_of(rotate_in_place(), room_map.lattice)
    for res, expected in zip((0.1, 0.2), whole):
        assert np.array_equal(chunked.occupancy_grid(res, ROOM_LO - 1.0, ROOM_HI + 1.0)[1], expected)
    # the digest hashes the pool's rows of observed blocks in key order: one stream per array, as one pass did
    keys, rows = room_map._observed_rows()
    weight, total = room_map._weight[rows], room_map._sum[rows]
    h = hashlib.blake2b(digest_size=16)
    h.update(room_map.lattice.describe().encode())
    for array in (keys, weight, total):
        h.update(np.ascontiguousarray(array).astype(array.dtype.newbyteorder("<")).tobytes())
    assert h.hexdigest() == digest
