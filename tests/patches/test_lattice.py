import numpy as np
import open3d as o3d
import pytest

from swarm.config import MappingSettings
from swarm.patches.lattice import Lattice


def test_from_settings_and_equality() -> None:
    settings = MappingSettings(voxel_size_m=0.2, block_resolution=8, truncation_voxels=3.0)
    lattice = Lattice.from_settings(settings)
    assert lattice == Lattice(0.2, 8, 3.0, (0.0, 0.0, 0.0), "dropoff")
    assert lattice.block_size == pytest.approx(1.6)
    assert lattice.truncation_m == pytest.approx(0.6)
    assert lattice != Lattice(0.2, 8, 3.0, (0.0, 0.0, 0.1), "dropoff")
    assert lattice != Lattice(0.2, 8, 3.0)  # a bare Lattice keeps the plain TSDF: constant weights
    assert lattice != Lattice(0.2, 8, 3.0, weight_law="inverse_square")
    with pytest.raises(ValueError):
        Lattice(voxel_size=0.0)


def test_point_voxel_block_mappings_round_trip() -> None:
    lattice = Lattice(0.1, 8, 4.0, origin=(1.0, -2.0, 0.5))
    rng = np.random.default_rng(1)
    index = rng.integers(-500, 500, size=(1000, 3))
    points = lattice.voxel_to_point(index)
    assert np.array_equal(lattice.point_to_voxel(points + rng.uniform(-0.049, 0.049, size=points.shape)), index)
    keys, flat = lattice.voxel_to_block(index)
    back = lattice.block_voxel_indices(keys)[np.arange(len(keys)), flat]
    assert np.array_equal(back, index)
    assert np.array_equal(lattice.point_to_block(points + 1e-6), np.floor_divide(index, 8))


def test_conventions_match_open3d_voxel_block_grid() -> None:
    lattice = Lattice(0.1, 8, 4.0)
    vbg = o3d.t.geometry.VoxelBlockGrid(
        ("tsdf", "weight"), (o3d.core.float32, o3d.core.float32), ((1), (1)), 0.1, 8, 16, o3d.core.Device("CPU:0")
    )
    keys = np.array([[1, -2, 3], [-4, 0, 7]], dtype=np.int32)
    buf, _ = vbg.hashmap().activate(o3d.core.Tensor(keys))
    coords, flat = vbg.voxel_coordinates_and_flattened_indices(buf)
    coords, flat = coords.numpy(), flat.numpy()
    rows = np.argsort(buf.numpy())
    r3 = lattice.voxels_per_block
    for key, row in zip(keys, buf.numpy()):
        mine = lattice.voxel_to_point(lattice.block_voxel_indices(key)[0])
        theirs = coords[(flat // r3) == row][np.argsort(flat[(flat // r3) == row] % r3)]
        assert np.allclose(mine, theirs, atol=1e-5)
    assert len(rows) == 2


def test_block_bounds_cover_sample_points() -> None:
    lattice = Lattice(0.1, 8, 4.0)
    lo, hi = lattice.block_bounds(np.array([[0, 0, 0], [1, -1, 2]]))
    assert np.allclose(lo, [0.0, -0.8, 0.0])
    assert np.allclose(hi, [1.5, 0.7, 2.3])
