import math

import numpy as np
import pytest

from swarm.explore.grid import OccupancyGrid
from tests.explore.synthetic import empty_grid, fill


def _cube_distance(offsets: np.ndarray, resolution: float) -> np.ndarray:
    """Distance between two grid cubes whose indices differ by `offsets` (..., 3)."""
    gaps = np.maximum(np.abs(offsets) - 1, 0) * resolution
    return np.linalg.norm(gaps, axis=-1)


def _centre_to_cube_distance(offsets: np.ndarray, resolution: float) -> np.ndarray:
    """Distance from a cell centre to a cube whose index differs by `offsets`."""
    gaps = np.maximum(np.abs(offsets) - 0.5, 0) * resolution
    return np.linalg.norm(gaps, axis=-1)


def test_index_and_centre_round_trip() -> None:
    grid = OccupancyGrid(np.array([-3.0, 1.25, -0.5]), 0.15, np.zeros((17, 9, 5), dtype=bool))
    rng = np.random.default_rng(1)
    for idx in rng.integers(0, grid.shape, size=(200, 3)):
        centre = grid.centre_of(idx)
        assert grid.index_of(centre) == tuple(int(v) for v in idx)
        jitter = rng.uniform(-0.49, 0.49, 3) * grid.resolution
        assert grid.index_of(centre + jitter) == tuple(int(v) for v in idx)
    np.testing.assert_allclose(grid.centre_of((0, 0, 0)), [-2.925, 1.325, -0.425])


def test_points_outside_the_grid_have_no_index_and_are_not_free() -> None:
    grid = empty_grid((2.0, 1.0, 1.0), origin=(1.0, 1.0, 0.0))
    assert grid.shape == (10, 5, 5)
    assert grid.index_of((1.0, 1.0, 0.0)) == (0, 0, 0)
    assert grid.index_of((2.999, 1.999, 0.999)) == (9, 4, 4)
    for outside in [(3.0, 1.5, 0.5), (0.999, 1.5, 0.5), (2.0, 2.0, 0.5), (2.0, 1.5, -0.01), (math.nan, 1.5, 0.5)]:
        assert grid.index_of(outside) is None
        assert not grid.is_free(outside)
    assert grid.is_free((2.0, 1.5, 0.5))
    grid.occupied[grid.index_of((2.0, 1.5, 0.5))] = True
    assert not grid.is_free((2.0, 1.5, 0.5))


@pytest.mark.parametrize(("resolution", "radius"), [(0.2, 0.3), (0.2, 0.4), (0.1, 0.25), (0.25, 0.1)])
def test_inflation_grows_obstacles_by_the_radius_and_less_than_a_cell_more(resolution: float, radius: float) -> None:
    n = 15
    occupied = np.zeros((n, n, n), dtype=bool)
    centre = np.array([7, 7, 7])
    occupied[tuple(centre)] = True
    grid = OccupancyGrid(np.zeros(3), resolution, occupied)

    blocked = grid.inflate(radius).occupied

    offsets = np.stack(np.meshgrid(*(np.arange(n) - c for c in centre), indexing="ij"), axis=-1)
    centre_distance = _centre_to_cube_distance(offsets, resolution)
    assert blocked[centre_distance <= radius].all(), "a cell centre within the radius stayed free"
    assert not blocked[centre_distance > radius + resolution].any(), "grew by more than a cell beyond the radius"
    # Exactly the cells with some point closer than the radius, so every point of a free cell is safe.
    np.testing.assert_array_equal(blocked, _cube_distance(offsets, resolution) < radius)
    assert occupied.sum() == 1, "inflate must not modify the grid it is called on"


def test_inflation_by_zero_is_the_occupied_set() -> None:
    grid = fill(empty_grid((2.0, 2.0, 1.0)), (0.5, 0.5, 0.5), (0.9, 0.9, 0.9))
    np.testing.assert_array_equal(grid.inflate(0.0).occupied, grid.occupied)
    assert not empty_grid((1.0, 1.0, 1.0)).inflate(0.3).occupied.any()


def test_unknown_cells_block_only_when_asked() -> None:
    grid = empty_grid((3.0, 3.0, 1.0))
    grid.unknown = np.zeros(grid.shape, dtype=bool)
    grid.unknown[5:10, 5:10, :] = True
    as_free = grid.inflate(0.2, unknown_is_occupied=False)
    as_blocked = grid.inflate(0.2, unknown_is_occupied=True)
    assert not as_free.occupied.any()
    np.testing.assert_array_equal(as_free.unknown, grid.unknown)
    assert as_blocked.occupied[grid.unknown].all()
    assert as_blocked.occupied.sum() > grid.unknown.sum()  # inflated too
    assert as_blocked.unknown is None


def test_segment_through_a_wall_is_blocked_and_along_it_free() -> None:
    grid = fill(empty_grid((4.0, 4.0, 2.0)), (2.0, 0.0, 0.0), (2.1, 4.0, 2.0))
    assert not grid.segment_is_free((0.5, 1.0, 1.0), (3.5, 3.0, 1.0))
    assert grid.segment_is_free((0.5, 0.5, 1.0), (1.9, 3.5, 1.5))
    assert grid.segment_is_free((2.25, 0.1, 0.1), (3.9, 3.9, 1.9))
    assert not grid.segment_is_free((1.0, 1.0, 1.0), (1.0, 1.0, 2.5)), "leaves the grid"
    assert grid.segment_is_free((1.0, 1.0, 1.0), (1.0, 1.0, 1.0))
    assert not grid.segment_is_free((2.1, 1.0, 1.0), (2.1, 1.0, 1.0))


def test_segment_clipping_a_corner_of_a_cell_is_blocked() -> None:
    grid = empty_grid((1.0, 1.0, 0.2))
    grid.occupied[2, 2, 0] = True  # the square [0.4, 0.6] x [0.4, 0.6]
    # Through (0.41, 0.59), 0.01 m inside the corner at (0.4, 0.6): a 0.03 m chord, far below resolution / 2.
    assert not grid.segment_is_free((0.21, 0.39, 0.1), (0.61, 0.79, 0.1))
    assert grid.segment_is_free((0.19, 0.41, 0.1), (0.59, 0.81, 0.1))


def test_segment_through_a_corner_between_two_blocked_cells_is_free() -> None:
    # Only the shared corner is touched; with a conservatively inflated grid that point keeps full clearance.
    grid = empty_grid((0.4, 0.4, 0.2))
    grid.occupied[1, 0, 0] = grid.occupied[0, 1, 0] = True
    assert grid.segment_is_free(grid.centre_of((0, 0, 0)), grid.centre_of((1, 1, 0)))
    grid.occupied[:] = False
    grid.occupied[0, 0, 0] = grid.occupied[1, 1, 0] = True
    assert grid.segment_is_free(grid.centre_of((0, 1, 0)), grid.centre_of((1, 0, 0)))
    # The same through a 3D corner, with rounding in the crossing parameters (non-round origin and size).
    grid = OccupancyGrid(np.array([0.37, -1.13, 2.9]), 0.15, np.ones((2, 2, 2), dtype=bool))
    grid.occupied[0, 1, 1] = grid.occupied[1, 0, 0] = False
    assert grid.segment_is_free(grid.centre_of((0, 1, 1)), grid.centre_of((1, 0, 0)))


def test_segment_check_matches_dense_sampling() -> None:
    rng = np.random.default_rng(7)
    grid = empty_grid((3.0, 3.0, 3.0), resolution=0.25, origin=(-1.0, 0.5, 0.0))
    grid.occupied[:] = rng.random(grid.shape) < 0.05
    outcomes = []
    for _ in range(300):
        a = grid.origin + rng.uniform(0, 3.0, 3)
        b = np.clip(a + rng.normal(0, 1.0, 3), grid.origin, grid.origin + 2.999)
        steps = max(2, int(np.linalg.norm(b - a) / (grid.resolution / 200)))
        samples = a + np.linspace(0, 1, steps)[:, None] * (b - a)
        outcomes.append(grid.segment_is_free(a, b))
        assert outcomes[-1] == grid.points_are_free(samples).all(), (a, b)
    assert 0.25 < np.mean(outcomes) < 0.75


def test_nearest_free_snaps_to_the_closest_free_centre_within_reach() -> None:
    grid = fill(empty_grid((2.0, 2.0, 0.2)), (0.0, 0.0, 0.0), (0.7, 2.0, 0.2))  # x < 0.8 blocked
    snapped = grid.nearest_free((0.65, 1.05, 0.1), max_radius=0.5)
    assert snapped is not None
    np.testing.assert_allclose(snapped, [0.9, 1.1, 0.1])
    assert grid.nearest_free((0.1, 1.0, 0.1), max_radius=0.5) is None
    np.testing.assert_allclose(grid.nearest_free((1.52, 0.33, 0.1), max_radius=0.2), [1.5, 0.3, 0.1])
