import dataclasses
import itertools
import math

import numpy as np
import pytest
from scipy import ndimage

from swarm.config import ExploreSettings, Vec3
from swarm.explore.frontiers import ExplorationGrid, Frontier
from swarm.explore.grid import OccupancyGrid
from swarm.explore.planner import NoPathError, path_is_free, plan_path
from swarm.patches.fused import FREE, OCCUPIED, UNKNOWN
from tests.explore.synthetic import room_states, set_states, state_grid, warehouse_states

RES = 0.2
# A point drone: these tests pin the grid's geometry cell by cell; the airframe's column has tests of its own.
SETTINGS = ExploreSettings(body_height_m=0.0)
# No speck filter: for the tests whose unknown pockets are a few cells, smaller than the default min_unknown_m3.
POCKETS = SETTINGS.model_copy(update={"min_unknown_m3": 0.0})
LEFT: Vec3 = (1.0, 3.0, 1.5)  # a drone in the left half of the 8 x 6 x 3 m room


def _grid(states: np.ndarray, settings: ExploreSettings = SETTINGS, top_z: float = 3.0, **kwargs) -> ExplorationGrid:
    return ExplorationGrid.from_states((0.0, 0.0, 0.0), RES, states, settings, floor_z=0.0, top_z=top_z, **kwargs)


def _cell(p: Vec3) -> tuple[int, int, int]:
    i, j, k = (int(v) for v in np.floor(np.asarray(p) / RES))
    return i, j, k


def _random_states(
    rng: np.random.Generator, size: tuple[int, int, int], p_unknown: float, p_occupied: float
) -> np.ndarray:
    """Independent random cell states, FREE for the rest of the probability."""
    p = [p_unknown, 1.0 - p_unknown - p_occupied, p_occupied]
    return rng.choice(np.array([UNKNOWN, FREE, OCCUPIED], dtype=np.uint8), size=size, p=p)


def _open_unknown(states: np.ndarray) -> np.ndarray:
    """The UNKNOWN cells with no OCCUPIED cell among their 26 neighbours, written out shift by shift (no scipy)."""
    occupied = np.pad(states == OCCUPIED, 1)
    nx, ny, nz = states.shape
    near = np.zeros(states.shape, dtype=bool)
    for dx, dy, dz in itertools.product(range(3), repeat=3):
        near |= occupied[dx : dx + nx, dy : dy + ny, dz : dz + nz]
    return (states == UNKNOWN) & ~near


def _free_face_neighbours(mask: np.ndarray, states: np.ndarray) -> np.ndarray:
    """The FREE cells sharing a face with a cell of `mask`, written out axis by axis."""
    padded = np.pad(mask, 1)
    nx, ny, nz = states.shape
    near = np.zeros(states.shape, dtype=bool)
    for axis, step in itertools.product(range(3), (-1, 1)):
        start = [1, 1, 1]
        start[axis] += step
        near |= padded[start[0] : start[0] + nx, start[1] : start[1] + ny, start[2] : start[2] + nz]
    return near & (states == FREE)


def _frontier_cell_mask(states: np.ndarray) -> np.ndarray:
    """The frontier cells before any reach test: FREE cells 6-adjacent to an open unknown cell."""
    return _free_face_neighbours(_open_unknown(states), states)


def _six_neighbour_states(states: np.ndarray, cell: tuple[int, int, int]) -> list[int]:
    found = []
    for axis, step in itertools.product(range(3), (-1, 1)):
        n = list(cell)
        n[axis] += step
        if 0 <= n[axis] < states.shape[axis]:
            found.append(int(states[tuple(n)]))
    return found


def test_frontiers_lie_on_the_free_unknown_boundary() -> None:
    states = room_states(known_to_x=4.0)
    frontiers = _grid(states).frontiers(LEFT)
    assert frontiers
    open_unknown = _open_unknown(states)
    for f in frontiers:
        cell = _cell(f.point)
        assert states[cell] == FREE
        assert UNKNOWN in _six_neighbour_states(states, cell)
        assert open_unknown[cell[0] + 1, cell[1], cell[2]]  # the unknown neighbour is open, not a crevice
        assert f.point[0] == pytest.approx(3.9)  # the last known layer before x = 4 m
    assert [f.gain for f in frontiers] == sorted((f.gain for f in frontiers), reverse=True)


def test_frontier_cells_are_grouped_by_component_and_cluster_bins() -> None:
    # The boundary is the free layer at x = 3.9 m (free cells 1..28 in y, 1..13 in z). The unknown cells across
    # it at x = 4.1 m that touch the known walls, floor or ceiling of the layer x = 3.9 m (y cells 1 and 28, z
    # cells 1 and 13) are crevices, not open unknown: 26 frontier cells across y (0.5..5.5 m) by 11 up z
    # (0.5..2.5 m) remain, low and high cells outside the flight band included. Bins of 1.2 m (6 cells) cut it
    # into 5 (y: 2-5, 6-11, 12-17, 18-23, 24-27) x 3 (z: 2-5, 6-11, 12) groups. No minimum gain: this is grouping.
    states = room_states(known_to_x=4.0)
    grouping = SETTINGS.model_copy(update={"min_gain_m3": 0.0})
    frontiers = _grid(states, grouping).frontiers(LEFT)
    assert int(_frontier_cell_mask(states).sum()) == 26 * 11
    assert len(frontiers) == 15
    assert sum(f.cells for f in frontiers) == 26 * 11
    assert sorted(f.cells for f in frontiers) == sorted(y * z for y in (4, 6, 6, 6, 4) for z in (4, 6, 1))
    assert len({f.point for f in frontiers}) == 15
    for f in frontiers:
        assert 0.5 - 1e-9 <= f.point[1] <= 5.5 + 1e-9 and 0.5 - 1e-9 <= f.point[2] <= 2.5 + 1e-9
    # Every group faces half an unknown room: the default minimum gain keeps them all.
    assert len(_grid(states).frontiers(LEFT)) == 15
    coarse = _grid(states, grouping.model_copy(update={"cluster_size_m": 10.0}))
    [single] = coarse.frontiers(LEFT)
    assert single.cells == 26 * 11
    # The cell nearest the mean: layer 7 of 2..12 in z, and one of the two middle columns of 2..27 in y.
    assert single.point[0] == pytest.approx(3.9) and single.point[2] == pytest.approx(1.5)
    assert single.point[1] == pytest.approx(2.9) or single.point[1] == pytest.approx(3.1)


def test_frontier_components_are_separate_groups_even_in_one_bin() -> None:
    states = room_states(known_to_x=8.0)
    for y in (1.9, 3.3):  # two unknown cells 1.4 m apart: neither shells nor gain cubes touch
        set_states(states, (2.1, y, 1.5), (2.1, y, 1.5), UNKNOWN)
    settings = POCKETS.model_copy(update={"cluster_size_m": 10.0, "min_gain_m3": 0.0})
    frontiers = _grid(states, settings).frontiers(LEFT)
    assert [f.cells for f in frontiers] == [6, 6]
    assert [f.gain for f in frontiers] == pytest.approx([RES**3] * 2)


@pytest.mark.parametrize(("length", "groups"), [(1, [5]), (2, [8, 2])])
def test_groups_of_a_single_frontier_cell_are_dropped(length: int, groups: list[int]) -> None:
    # An unknown rod of 1 or 2 cells along y, in mid-air in a known room, in the last cell column (x = 2.3 m) of
    # its 1.2 m cluster bin: the free cells past its +x face (x = 2.5 m) are a group of their own, `length`
    # cells; the 3 * length + 2 cells of its other faces are one group in the rod's bin. One cell is dropped,
    # two are kept. (A gap in a wall can no longer show this: it touches the wall, so it is a crevice.)
    states = room_states(known_to_x=8.0)
    set_states(states, (2.3, 2.9, 1.5), (2.3, 2.9 + 0.2 * (length - 1), 1.5), UNKNOWN)
    assert _open_unknown(states).sum() == length
    assert int(_frontier_cell_mask(states).sum()) == 4 * length + 2
    frontiers = _grid(states, POCKETS.model_copy(update={"min_gain_m3": 0.0})).frontiers(LEFT)
    assert sorted(f.cells for f in frontiers) == sorted(groups)
    assert all(f.point[0] == pytest.approx(2.1) for f in frontiers if f.cells > 2)
    assert all(f.point[0] == pytest.approx(2.5) for f in frontiers if f.cells <= 2)


def test_a_fully_known_closed_room_has_no_frontiers() -> None:
    grid = _grid(room_states(known_to_x=8.0))
    assert grid.reachable(LEFT).any()
    assert grid.frontiers(LEFT) == []
    assert grid.unknown_fraction() == 0.0
    assert not grid.is_frontier_near((4.0, 3.0, 1.5), 10.0)


def test_unknown_fraction_counts_the_flight_band() -> None:
    # The band is the layers k = 3..13 (z 0.6..2.7 m): 40 x 30 x 11 cells, the 20 x 30 x 11 at x >= 4 m unknown.
    # Of the layer x = 4.1 m, the cells touching the known walls of x = 3.9 m are crevices: all 30 of k = 13
    # (next to the ceiling, k = 14) and 4 per layer (y cells 0, 1, 28, 29) of k = 3..12.
    states = room_states(known_to_x=4.0)
    expected = (20 * 30 * 11 - (30 + 4 * 10)) / (40 * 30 * 11)
    assert _grid(states).unknown_fraction() == pytest.approx(expected)
    assert expected == pytest.approx(_open_unknown(states)[:, :, 3:14].mean())
    # Known all through: nothing unknown, open or not.
    assert _grid(room_states(known_to_x=8.0)).unknown_fraction() == 0.0


@pytest.mark.parametrize(
    ("door", "known_behind_to_x", "kept"),
    [
        (False, 4.2, False),  # closed wall, nothing known behind it: the wall is no frontier
        (False, 4.6, False),  # free strip just behind the wall, within reach of the near side: no line of sight
        (False, 6.0, False),  # a known room behind the wall whose frontier is out of reach
        (True, 4.2, True),  # open door onto unknown space: the doorway is the frontier
        (True, 6.0, True),  # open door onto known space: its far frontier is reachable through the door
    ],
)
def test_frontiers_behind_a_closed_wall_are_dropped_and_behind_an_open_door_kept(
    door: bool, known_behind_to_x: float, kept: bool
) -> None:
    states = room_states(known_to_x=known_behind_to_x, wall_x=4.0, door=door)
    grid = _grid(states)
    behind = [f for f in grid.frontiers(LEFT) if f.point[0] > 4.0]
    assert bool(behind) == kept
    assert grid.is_frontier_near((known_behind_to_x - 0.1, 3.0, 1.5), 0.2) == (known_behind_to_x > 4.2 or door)
    for f in behind:
        assert grid.reachable(LEFT)[_cell(f.viewpoint)]
    if known_behind_to_x == 4.6:
        # The strip's frontier (x = 4.5 m) is within reach_m of reachable cells: only line of sight drops it.
        reachable_centres = (np.argwhere(grid.reachable(LEFT)) + 0.5) * RES
        gap = np.linalg.norm(reachable_centres - np.array([4.5, 3.0, 1.5]), axis=1).min()
        assert gap <= SETTINGS.reach_m


def _cluttered_room() -> np.ndarray:
    """The half-known room with a pillar and a low table near the boundary, and an unknown pocket under it."""
    states = room_states(known_to_x=5.0)
    set_states(states, (3.0, 1.0, 0.0), (3.4, 1.4, 3.0), OCCUPIED)
    set_states(states, (3.4, 3.5, 0.8), (4.6, 4.8, 0.9), OCCUPIED)
    set_states(states, (3.6, 3.7, 0.2), (4.4, 4.6, 0.6), UNKNOWN)
    return states


def test_viewpoints_are_safe_reachable_in_the_band_and_within_reach() -> None:
    grid = _grid(_cluttered_room())
    reachable = grid.reachable(LEFT)
    frontiers = grid.frontiers(LEFT)
    assert len(frontiers) > 5
    for f in frontiers:
        assert grid.planning_grid.is_free(f.viewpoint)
        assert reachable[_cell(f.viewpoint)]
        assert np.linalg.norm(np.subtract(f.point, f.viewpoint)) <= SETTINGS.reach_m + 1e-9
        assert SETTINGS.min_altitude_m <= f.viewpoint[2] <= 3.0 - SETTINGS.ceiling_margin_m
        assert _sight(_cluttered_room()).segment_is_free(f.viewpoint, f.point)


def _sight(states: np.ndarray) -> OccupancyGrid:
    """A grid blocking only the occupied cells: exact line-of-sight checks through `segment_is_free`."""
    return OccupancyGrid(np.zeros(3), RES, states == OCCUPIED)


def test_a_viewpoint_hidden_behind_an_obstacle_is_replaced_by_one_in_sight() -> None:
    # A thin plate 0.5 m before the boundary: the nearest reachable cells to the frontier behind it are on the
    # plate's far side; a reachable cell beside the plate, a little farther, sees it.
    states = room_states(known_to_x=4.0)
    set_states(states, (3.4, 2.4, 1.2), (3.59, 3.59, 2.39), OCCUPIED)
    grid = _grid(states)
    hidden = [f for f in grid.frontiers(LEFT) if 2.4 < f.point[1] < 3.6 and 1.2 < f.point[2] < 2.4]
    assert len(hidden) == 1
    point, viewpoint = np.array(hidden[0].point), np.array(hidden[0].viewpoint)
    assert _sight(states).segment_is_free(viewpoint, point)
    assert np.linalg.norm(viewpoint - point) <= SETTINGS.reach_m + 1e-9
    reachable_centres = (np.argwhere(grid.reachable(LEFT)) + 0.5) * RES
    assert np.linalg.norm(reachable_centres - point, axis=1).min() < np.linalg.norm(viewpoint - point)


def test_the_planner_reaches_every_frontier_viewpoint() -> None:
    grid = _grid(_cluttered_room())
    for f in grid.frontiers(LEFT):
        path = plan_path(grid.planning_grid, LEFT, f.viewpoint)
        assert path[-1] == pytest.approx(f.viewpoint)
        assert path_is_free(grid.planning_grid, path)


def test_the_flight_band_excludes_viewpoints_below_the_minimum_altitude() -> None:
    settings = SETTINGS.model_copy(update={"min_altitude_m": 1.2})
    grid = _grid(room_states(known_to_x=4.0), settings)
    frontiers = grid.frontiers(LEFT)
    assert min(f.point[2] for f in frontiers) < 1.2  # low frontiers stay: they are seen from above
    assert min(f.viewpoint[2] for f in frontiers) >= 1.2
    below = np.array([(x, y, 1.1) for x in np.arange(0.5, 4.0, 0.2) for y in np.arange(0.5, 5.6, 0.2)])
    assert not grid.planning_grid.points_are_free(below).any()
    assert grid.planning_grid.is_free((2.0, 3.0, 1.3))
    # The top of the band: top_z - ceiling_margin_m = 2.2 m, below the ceiling's own inflation (2.3 m is safe).
    assert _grid(room_states(known_to_x=4.0)).planning_grid.is_free((2.0, 3.0, 2.3))
    lowered = _grid(room_states(known_to_x=4.0), top_z=2.5)
    assert lowered.planning_grid.is_free((2.0, 3.0, 2.1)) and not lowered.planning_grid.is_free((2.0, 3.0, 2.3))
    assert max(f.viewpoint[2] for f in lowered.frontiers(LEFT)) == pytest.approx(2.1)


def test_a_drone_needs_room_for_its_airframe_above_its_position() -> None:
    # The room's ceiling is cells k >= 14 (z >= 2.8 m); inflated by 0.25 m it blocks k = 12, 13 (z 2.4..2.8 m),
    # so a point may be at k = 11 (2.2..2.4 m). A 0.45 m airframe's top, 0.45 m above its cell's centre, must
    # keep the 0.25 m clearance too: two cells above the position clear (their clearance reaches 0.25 m above
    # the second's top). The highest safe position is k = 9 (centre 1.9 m): the top at 2.35 m, 0.45 m under the
    # ceiling (0.35 m from the cell's top). A 0.65 m airframe needs three cells: k = 8.
    states = room_states(known_to_x=8.0)
    point = SETTINGS.model_copy(update={"ceiling_margin_m": 0.01})
    airframe = point.model_copy(update={"body_height_m": 0.45})
    tall = point.model_copy(update={"body_height_m": 0.65})
    assert ExploreSettings().body_height_m == 0.45
    heights = [0.9 + 0.2 * k for k in range(8)]  # cell centres 0.9 .. 2.3 m
    for settings, safe_layers in ((point, 8), (airframe, 6), (tall, 5)):
        grid = _grid(states, settings)
        assert [grid.planning_grid.is_free((2.0, 3.0, z)) for z in heights] == [True] * safe_layers + [False] * (
            8 - safe_layers
        ), settings.body_height_m
    # A lintel (a slab from 2.0 to 2.2 m) over part of the room: a point may pass right under it (centre 1.5 m),
    # a drone not; at 1.3 m its top would keep exactly the clearance, which the conservative cells refuse.
    set_states(states, (3.0, 0.0, 2.0), (4.99, 5.99, 2.19), OCCUPIED)
    point_grid, airframe_grid = _grid(states, point), _grid(states, airframe)
    assert point_grid.planning_grid.is_free((4.0, 3.0, 1.5))
    assert not airframe_grid.planning_grid.is_free((4.0, 3.0, 1.5))
    assert not airframe_grid.planning_grid.is_free((4.0, 3.0, 1.3))
    assert airframe_grid.planning_grid.is_free((4.0, 3.0, 1.1))
    # the drone's own position stays usable although the cells above it were never seen
    states[10, 15, 4:9] = UNKNOWN
    assert airframe_grid.planning_grid.is_free((2.1, 3.1, 0.9))
    assert not _grid(states, airframe).planning_grid.is_free((2.1, 3.1, 0.9))
    assert _grid(states, airframe, free_points=[(2.1, 3.1, 0.9)]).planning_grid.is_free((2.1, 3.1, 0.9))


def test_a_drone_flies_only_where_the_space_above_its_airframe_has_been_seen() -> None:
    # The room of the test above with its top unseen from z = 2.4 m (the ceiling and the layers under it): a
    # drone's position needs body_height_m + clearance_m = 0.7 m, 4 cells, of seen space above its cell, so
    # the highest safe layer is k = 7 (1.4..1.6 m) where, with the ceiling seen, it was k = 9.
    states = room_states(known_to_x=8.0)
    airframe = SETTINGS.model_copy(update={"ceiling_margin_m": 0.01, "body_height_m": 0.45})
    heights = [0.9 + 0.2 * k for k in range(8)]  # cell centres 0.9 .. 2.3 m
    assert [_grid(states, airframe).planning_grid.is_free((2.0, 3.0, z)) for z in heights] == [True] * 6 + [False] * 2
    states[:, :, 12:] = UNKNOWN
    unseen = _grid(states, airframe)
    assert [unseen.planning_grid.is_free((2.0, 3.0, z)) for z in heights] == [True] * 4 + [False] * 4
    # a drone up there (it climbed before the map caught up) can still plan from where it is
    here = (2.1, 3.1, 2.1)
    assert not unseen.planning_grid.is_free(here)
    assert _grid(states, airframe, free_points=[here]).planning_grid.is_free(here)


def test_gain_is_larger_facing_a_large_unknown_region_than_a_small_pocket() -> None:
    states = room_states(known_to_x=6.0)
    set_states(states, (2.0, 3.0, 1.2), (2.39, 3.39, 1.59), UNKNOWN)  # a 2 x 2 x 2 cell pocket in mid-air
    no_minimum = POCKETS.model_copy(update={"min_gain_m3": 0.0})
    frontiers = _grid(states, no_minimum).frontiers(LEFT)
    pocket = [f for f in frontiers if f.point[0] < 3.0]
    large = [f for f in frontiers if f.point[0] > 5.0]
    # The pocket's 6 faces of 4 cells, cut by the bins at x = 2.4 m and z = 1.2 m into 3 groups.
    assert len(pocket) == 3 and sum(f.cells for f in pocket) == 24
    assert large
    assert all(f.gain == pytest.approx(8 * RES**3) for f in pocket)
    assert min(f.gain for f in large) > 5 * max(f.gain for f in pocket)
    # A minimum just above the pocket's gain drops the pocket but keeps the large region; one equal to it keeps
    # the pocket (gain >= minimum).
    for minimum, pocket_kept in ((8 * RES**3 + 1e-9, False), (8 * RES**3 - 1e-9, True)):
        kept = _grid(states, POCKETS.model_copy(update={"min_gain_m3": minimum})).frontiers(LEFT)
        assert len([f for f in kept if f.point[0] < 3.0]) == (3 if pocket_kept else 0)
        assert len([f for f in kept if f.point[0] > 5.0]) == len(large)
    # So does the default minimum.
    kept = _grid(states).frontiers(LEFT)
    assert not [f for f in kept if f.point[0] < 3.0]
    assert len([f for f in kept if f.point[0] > 5.0]) == len(large)


@pytest.mark.parametrize("p_occupied", [0.1, 0.01])
def test_gain_at_counts_open_unknown_cells_in_the_cube_and_matches_the_frontiers(p_occupied: float) -> None:
    rng = np.random.default_rng(3)
    states = _random_states(rng, (24, 18, 12), p_unknown=0.3, p_occupied=p_occupied)
    grid = _grid(states, POCKETS)  # open unknown cells here are mostly isolated: no speck filter
    half = round(SETTINGS.gain_radius_m / RES)
    cells = rng.integers(0, states.shape, size=(40, 3))
    open_unknown = _open_unknown(states)
    cubes = [tuple(slice(max(c - half, 0), c + half + 1) for c in cell) for cell in cells]
    expected = np.array([np.sum(open_unknown[cube]) for cube in cubes]) * RES**3
    every_unknown = np.array([np.sum(states[cube] == UNKNOWN) for cube in cubes]) * RES**3
    assert np.all(expected > 0) and np.all(expected < every_unknown)  # crevices are left out, open cells are not
    points = (cells + rng.uniform(0.01, 0.99, size=cells.shape)) * RES
    np.testing.assert_allclose(grid.gain_at(points), expected)
    outside = np.array([(-0.1, 1.0, 1.0), (1.0, 3.61, 1.0), (1.0, 1.0, 2.45), (np.nan, 1.0, 1.0)])
    assert grid.gain_at(outside).tolist() == [0.0] * 4

    room = _grid(_cluttered_room())
    frontiers = room.frontiers(LEFT)
    np.testing.assert_allclose(room.gain_at(np.array([f.point for f in frontiers])), [f.gain for f in frontiers])


def test_free_points_make_the_drones_unknown_cell_plannable() -> None:
    states = state_grid((4.0, 4.0, 3.0), UNKNOWN)
    position: Vec3 = (2.05, 2.05, 1.55)
    blind = _grid(states)
    assert not blind.planning_grid.is_free(position)
    assert not blind.reachable(position).any()
    assert blind.frontiers(position) == []

    grid = _grid(states, free_points=[position])
    assert grid.planning_grid.is_free(position)
    assert grid.reachable(position)[_cell(position)]
    assert all(grid.planning_grid.is_free(f.viewpoint) for f in grid.frontiers(position))
    centres = (np.indices(states.shape).reshape(3, -1).T + 0.5) * RES
    # the position and the column above it that must have been seen: up to clearance_m over a point drone
    column = [np.add(position, (0.0, 0.0, j * RES)) for j in range(math.ceil(SETTINGS.clearance_m / RES))]
    ball = (np.min([np.linalg.norm(centres - p, axis=1) for p in column], axis=0) <= SETTINGS.clearance_m).reshape(
        states.shape
    )
    freed = int(ball.sum())
    assert blind.gain_at(np.array([position]))[0] - grid.gain_at(np.array([position]))[0] == pytest.approx(
        freed * RES**3
    )

    # An occupied cell next to the drone's stays occupied, and the drone's cell is not safe. Its 26 neighbours are
    # crevices, unknown but not open, freed or not: the gain falls by the freed cells outside them only.
    set_states(states, (2.2, 2.0, 1.4), (2.39, 2.19, 1.59), OCCUPIED)
    walled = _grid(states, free_points=[position])
    crevice = np.zeros(states.shape, dtype=bool)
    crevice[10:13, 9:12, 6:9] = True  # around the occupied cell (11, 10, 7); the drone's cell (10, 10, 7) in it
    assert states[11, 10, 7] == OCCUPIED and crevice[_cell(position)]
    assert np.array_equal(_open_unknown(states), ~crevice)
    freed_open = int(np.sum(ball & ~crevice))
    assert 0 < freed_open < freed - 1
    cube = tuple(slice(c - 5, c + 6) for c in _cell(position))  # the gain cube, well inside the grid
    unknown_before = _grid(states).gain_at(np.array([position]))[0]
    assert unknown_before == pytest.approx(np.sum(~crevice[cube]) * RES**3)
    assert walled.gain_at(np.array([position]))[0] == pytest.approx(np.sum(~crevice[cube] & ~ball[cube]) * RES**3)
    assert unknown_before - walled.gain_at(np.array([position]))[0] == pytest.approx(freed_open * RES**3)
    assert not walled.planning_grid.is_free(position)


@pytest.mark.parametrize("p_occupied", [0.1, 0.01])
def test_frontier_cells_are_the_free_cells_next_to_an_open_unknown_cell(p_occupied: float) -> None:
    states = _random_states(np.random.default_rng(5), (24, 18, 12), p_unknown=0.3, p_occupied=p_occupied)
    grid = _grid(states, POCKETS)  # open unknown cells here are mostly isolated: no speck filter
    expected = _frontier_cell_mask(states)
    next_to_unknown = _free_face_neighbours(states == UNKNOWN, states)
    assert expected.any() and (next_to_unknown & ~expected).any()  # some free cells border crevices only
    found = np.array([grid.is_frontier_near(tuple((np.array(c) + 0.5) * RES), 0.01) for c in np.ndindex(states.shape)])
    np.testing.assert_array_equal(found.reshape(states.shape), expected)


@pytest.mark.parametrize(
    ("offset", "is_open"),
    [
        ((1, 0, 0), False),  # a face
        ((1, 1, 0), False),  # an edge
        ((1, 1, 1), False),  # a corner
        ((2, 0, 0), True),
        ((2, 1, 1), True),
        ((2, 2, 2), True),
    ],
)
def test_an_unknown_cell_touching_an_occupied_cell_even_at_a_corner_is_a_crevice(
    offset: tuple[int, int, int], is_open: bool
) -> None:
    # One unknown cell in mid-air in a known room, one occupied cell at `offset` cells from it: sharing a face,
    # an edge or a corner (26-adjacent) makes it a crevice; one free cell between them leaves it open.
    states = room_states(known_to_x=8.0)
    unknown = (10, 15, 7)
    states[unknown] = UNKNOWN
    states[tuple(np.add(unknown, offset))] = OCCUPIED
    grid = _grid(states, POCKETS.model_copy(update={"min_gain_m3": 0.0}))
    centre = tuple((np.array(unknown) + 0.5) * RES)
    frontiers = grid.frontiers(LEFT)
    if is_open:
        assert [f.cells for f in frontiers] == [6]  # its 6 free face neighbours, one group
        assert grid.gain_at(np.array([centre]))[0] == pytest.approx(RES**3)
    else:
        assert frontiers == []
        assert grid.gain_at(np.array([centre]))[0] == 0.0
    assert grid.is_frontier_near(centre, 0.25) == is_open
    assert grid.unknown_fraction() == pytest.approx(is_open / (40 * 30 * 11))  # the band: layers 3..13


def _pocket_room(x0: float, thickness: int, box: bool) -> np.ndarray:
    """The known room with an unknown pocket `thickness` x 2 x 2 cells from x = `x0` (y 2.8..3.2, z 1.4..1.8 m),
    and with `box` an occupied box at x 0.6..0.8 m (cells i = 3), y 2.2..3.8, z 1.0..2.2 m."""
    states = room_states(known_to_x=8.0)
    if box:
        set_states(states, (0.6, 2.2, 1.0), (0.79, 3.8, 2.2), OCCUPIED)
    set_states(states, (x0, 2.8, 1.4), (x0 + 0.2 * thickness - 0.01, 3.19, 1.79), UNKNOWN)
    return states


@pytest.mark.parametrize(
    ("thickness", "box"),
    [(1, False), (2, True)],  # a patch on the wall x = 0; a pocket wedged between that wall and the box
)
def test_an_unknown_pocket_wedged_against_obstacles_makes_no_frontier_and_no_gain(thickness: int, box: bool) -> None:
    settings = POCKETS.model_copy(update={"min_gain_m3": 0.0})  # any gain at all would keep a group
    pocket_cells = thickness * 2 * 2
    surface = 2 * 4 + 4 * 2 * thickness  # free cells sharing a face with the pocket
    band_cells = 40 * 30 * 11
    for x0, wedged in ((0.2, True), (1.6, False)):  # against the wall at x = 0 (and the box); in open space
        states = _pocket_room(x0, thickness, box)
        assert np.sum(states == UNKNOWN) == pocket_cells
        centre = (x0 + 0.1 * thickness, 3.0, 1.6)
        grid = _grid(states, settings)
        # Whether wedged or not, the pocket's free face neighbours are within reach of the reachable space: only
        # the open-unknown rule decides.
        faces = _free_face_neighbours(states == UNKNOWN, states)
        assert faces.sum() == surface - (4 * (1 + box) if wedged else 0)  # the wall (and the box) cover x faces
        reachable = (np.argwhere(grid.reachable(LEFT)) + 0.5) * RES
        for face in (np.argwhere(faces) + 0.5) * RES:
            assert np.linalg.norm(reachable - face, axis=1).min() <= SETTINGS.reach_m
        frontiers = grid.frontiers(LEFT)
        if wedged:
            assert not _open_unknown(states).any()
            assert frontiers == []
            assert grid.gain_at(np.array([centre]))[0] == 0.0
            assert grid.unknown_fraction() == 0.0
            assert not grid.is_frontier_near(centre, 0.5)
        else:
            assert [f.cells for f in frontiers] == [surface]
            assert frontiers[0].gain == pytest.approx(pocket_cells * RES**3)
            assert grid.gain_at(np.array([centre]))[0] == pytest.approx(pocket_cells * RES**3)
            assert grid.unknown_fraction() == pytest.approx(pocket_cells / band_cells)
            assert grid.is_frontier_near(centre, 0.5)


def test_a_large_unknown_room_behind_an_open_door_has_frontiers_in_the_doorway() -> None:
    # The wall is the cells i = 20 (x 4.0..4.2 m); the door the cells y 12..17 (2.4..3.6 m) by z 1..9 (0.2..2.0
    # m), framed by occupied cells: jambs at y cells 11 and 18, the floor at z 0, the lintel at z 10. Beyond it
    # everything from x = 4.2 m is unknown: a 3.8 x 6 x 3 m room. The unknown cells just beyond the frame are
    # crevices, those beyond the middle of the door are open: the doorway cells facing them are frontier cells.
    states = room_states(known_to_x=4.2, wall_x=4.0, door=True)
    assert all(states[20, j, 5] == OCCUPIED for j in (11, 18)) and states[20, 14, 10] == OCCUPIED
    assert states[20, 14, 0] == OCCUPIED
    open_unknown = _open_unknown(states)
    assert open_unknown[21, 14, 5] and not open_unknown[21, 12, 5] and not open_unknown[21, 14, 9]
    expected = {(20, j, k) for j in range(13, 17) for k in range(2, 9)}
    assert {tuple(int(i) for i in c) for c in np.argwhere(_frontier_cell_mask(states))} == expected

    grid = _grid(states)  # default settings: the room behind clears the default minimum gain
    frontiers = grid.frontiers(LEFT)
    assert sorted(f.cells for f in frontiers) == [12, 16]  # z cells 6..8 and 2..5: two 1.2 m bins
    reachable = grid.reachable(LEFT)
    for f in frontiers:
        assert _cell(f.point) in expected
        assert f.gain >= SETTINGS.min_gain_m3 and f.gain > 2.0  # most of the gain cube is the room behind
        assert reachable[_cell(f.viewpoint)]
        path = plan_path(grid.planning_grid, LEFT, f.viewpoint)
        assert path_is_free(grid.planning_grid, path)
    # The same wall closed: no frontier at all.
    assert _grid(room_states(known_to_x=4.2, wall_x=4.0)).frontiers(LEFT) == []


def test_reachable_is_the_connected_safe_space_around_the_position() -> None:
    grid = _grid(room_states(known_to_x=8.0, wall_x=4.0))
    reachable = grid.reachable(LEFT)
    assert reachable[_cell(LEFT)] and not reachable[_cell((6.0, 3.0, 1.5))]
    assert grid.reachable((6.0, 3.0, 1.5))[_cell((6.0, 3.0, 1.5))]
    assert not (reachable & grid.planning_grid.occupied).any()
    assert not grid.reachable((4.1, 3.0, -5.0)).any()  # more than 1.5 m from any safe cell


@pytest.mark.parametrize("clearance", [0.35, 0.25, 0.5, 0.4, 0.2])
def test_safe_cells_are_the_free_cells_outside_the_inflated_obstacles(clearance: float) -> None:
    states = _random_states(np.random.default_rng(7), (30, 25, 20), p_unknown=0.1, p_occupied=0.03)
    settings = SETTINGS.model_copy(update={"clearance_m": clearance})
    grid = ExplorationGrid.from_states((0.0, 0.0, 0.0), RES, states, settings, floor_z=-10.0, top_z=10.0)
    inflated = OccupancyGrid(np.zeros(3), RES, states == OCCUPIED).inflate(clearance).occupied
    # ... and the cells with an unknown cell (or the grid's top) less than `clearance` above their top
    above = math.ceil(clearance / RES - 1e-9)
    nz = states.shape[2]
    under_unknown = np.zeros(states.shape, dtype=bool)
    for k in range(nz):
        column = states[:, :, k + 1 : k + 1 + above] == UNKNOWN
        under_unknown[:, :, k] = column.any(axis=2) | (k + above >= nz)
    np.testing.assert_array_equal(grid.planning_grid.occupied, inflated | (states != FREE) | under_unknown)


def test_a_half_explored_warehouse() -> None:
    states = warehouse_states(speckle=0.0)
    position: Vec3 = (2.0, 2.0, 1.5)
    grid = ExplorationGrid.from_states((0.0, 0.0, 0.0), RES, states, SETTINGS, floor_z=0.0, top_z=6.2)
    frontiers = grid.frontiers(position)
    boundary = [f for f in frontiers if f.point[0] > 19.0]
    assert len(boundary) > 50 and len(frontiers) > len(boundary)  # the rack shadows are frontiers too
    best = frontiers[0]
    assert best.point[0] > 19.0 and best.gain > 5.0  # facing the unexplored half
    assert 0.4 < grid.unknown_fraction() < 0.6
    path = plan_path(grid.planning_grid, position, best.viewpoint)
    assert path_is_free(grid.planning_grid, path)


def test_frontier_is_immutable() -> None:
    f = Frontier((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 1.0, 2)
    with pytest.raises(dataclasses.FrozenInstanceError):
        f.gain = 2.0  # type: ignore[misc]


def _door_states(first: int, last: int) -> tuple[np.ndarray, np.ndarray]:
    """A wall one 0.1 m voxel thick across y (y = 2.0..2.1 m) of a known 4 x 4 x 3 m room, with a doorway of
    the voxels first..last along x (no lintel): the occupied voxels, and the 0.2 m states the fused map exports
    from them (a cell is OCCUPIED when any of its voxels is)."""
    fine = np.zeros((40, 40, 30), dtype=bool)
    fine[:, 20, :] = True
    fine[first : last + 1, 20, :] = False
    fine[:, :, :2] = fine[:, :, -2:] = True  # floor and ceiling slabs
    coarse = fine.reshape(20, 2, 20, 2, 15, 2).any(axis=(1, 3, 5))
    return fine, np.where(coarse, np.uint8(OCCUPIED), np.uint8(FREE))


# (first, last door voxel), safe door cells from the 0.2 m cells, from the voxels; worked out by hand: a cell is
# safe when no voxel of it comes within 0.25 m of an obstacle (a jamb voxel, or the jamb's whole 0.2 m cell).
DOORS = [((15, 24), 0, 2), ((15, 25), 1, 2), ((14, 24), 1, 2), ((14, 23), 1, 1)]


@pytest.mark.parametrize(("door", "from_cells", "from_voxels"), DOORS)
def test_a_doorway_keeps_more_safe_cells_when_clearance_is_measured_from_the_voxels(
    door: tuple[int, int], from_cells: int, from_voxels: int
) -> None:
    fine, states = _door_states(*door)
    settings = SETTINGS.model_copy(update={"ceiling_margin_m": 0.01})
    coarse = ExplorationGrid.from_states((0, 0, 0), RES, states, settings, floor_z=0.0, top_z=3.0)
    voxels = ExplorationGrid.from_states((0, 0, 0), RES, states, settings, floor_z=0.0, top_z=3.0, occupied_fine=fine)
    in_door = np.array([(x, 2.1, 1.5) for x in np.arange(1.1, 3.0, 0.2)])
    assert coarse.planning_grid.points_are_free(in_door).sum() == from_cells
    passable = voxels.planning_grid.points_are_free(in_door)
    assert passable.sum() == from_voxels
    occupied_voxels = np.argwhere(fine) * 0.1
    for point in in_door[passable]:  # each is 0.25 m clear of every occupied voxel, cube to cube
        lo = np.floor(point / RES) * RES
        gap = np.maximum(np.maximum(occupied_voxels - (lo + RES), lo - (occupied_voxels + 0.1)), 0.0)
        assert np.linalg.norm(gap, axis=1).min() >= settings.clearance_m - 1e-9
    start, goal = (2.0, 1.0, 1.5), (2.0, 3.2, 1.5)
    assert path_is_free(voxels.planning_grid, plan_path(voxels.planning_grid, start, goal))
    if from_cells == 0:
        with pytest.raises(NoPathError):
            plan_path(coarse.planning_grid, start, goal)


def test_fine_occupancy_must_refine_the_grid_exactly() -> None:
    fine, states = _door_states(15, 25)
    with pytest.raises(ValueError, match="integer refinement"):
        ExplorationGrid.from_states(
            (0, 0, 0), RES, states, SETTINGS, floor_z=0.0, top_z=3.0, occupied_fine=fine[:, :-1]
        )


def test_cells_marked_occupied_by_hand_stay_obstacles_with_fine_occupancy() -> None:
    # a dead drone's last position is marked on the coarse states only: it must still be kept clear of
    fine, states = _door_states(15, 25)
    states[5, 5, 7] = OCCUPIED
    grid = ExplorationGrid.from_states((0, 0, 0), RES, states, SETTINGS, floor_z=0.0, top_z=3.0, occupied_fine=fine)
    assert not grid.planning_grid.is_free((1.1, 1.1, 1.5))
    assert not grid.planning_grid.is_free((1.3, 1.1, 1.5))  # within 0.25 m of the marked cell
    assert grid.planning_grid.is_free((1.1, 0.5, 1.5))


@pytest.mark.parametrize("shape", [(12, 9, 17), (10, 8, 64), (9, 7, 70)])  # packed columns, and taller than 64
def test_inflation_matches_a_brute_force_dilation(shape: tuple[int, int, int]) -> None:
    from swarm.explore.frontiers import _ball_offsets, _cube_offsets, _inflate

    occupied = np.random.default_rng(3).random(shape) < 0.03
    for radius in (0.5, 1.25, 2.5):
        ball = _ball_offsets(radius - 1e-9, strict=True)
        offsets = np.unique((ball[:, None, :] + _cube_offsets(1)[None, :, :]).reshape(-1, 3), axis=0)
        expected = np.zeros_like(occupied)
        nx, ny, nz = shape
        for dx, dy, dz in offsets:
            expected[max(dx, 0) : nx + min(dx, 0), max(dy, 0) : ny + min(dy, 0), max(dz, 0) : nz + min(dz, 0)] |= (
                occupied[max(-dx, 0) : nx - max(dx, 0), max(-dy, 0) : ny - max(dy, 0), max(-dz, 0) : nz - max(dz, 0)]
            )
        assert np.array_equal(_inflate(occupied, radius), expected), radius
    # radius 0.5 is the 26-neighbour dilation the grid uses to leave out crevices
    assert np.array_equal(_inflate(occupied, 0.5), ndimage.binary_dilation(occupied, structure=np.ones((3, 3, 3))))


@pytest.mark.parametrize(("f", "shape"), [(2, (24, 18, 44)), (3, (27, 21, 63)), (1, (9, 7, 17)), (2, (10, 8, 70))])
def test_inflation_taken_at_coarse_columns_is_the_fine_inflation_coarsened(f: int, shape: tuple[int, int, int]) -> None:
    """The planning grid's clearance from the 0.1 m voxels (`_blocked`) dilates at the coarse columns only; it must
    be the fine dilation coarsened, cell for cell, at the grid's edges too (and where it falls back: columns taller
    than 64 cells)."""
    from swarm.explore.frontiers import _coarsen, _inflate_all, _inflate_all_coarsened, _pack_columns

    occupied = np.random.default_rng(5).random(shape) < 0.02
    occupied[0, :, 3] = occupied[-1, 2, :] = True  # obstacles on the grid's faces
    radii = (1.25 * f, 2.25 * f, 0.0)
    expected = [_coarsen(m, f) for m in _inflate_all(occupied, radii)]
    got = _inflate_all_coarsened(occupied, radii, f)
    assert len(got) == 3 and all(np.array_equal(g, e) for g, e in zip(got, expected))
    if shape[2] <= 64:  # the packing: bit k of a column's word is its cell k
        words = _pack_columns(occupied)
        bits = (words[:, :, None] >> np.arange(shape[2], dtype=np.uint64)) & np.uint64(1)
        assert np.array_equal(bits.astype(bool), occupied)


@pytest.mark.parametrize(("shape", "density"), [((30, 20, 12), 0.3), ((9, 40, 7), 0.6), ((5, 5, 5), 0.0)])
def test_components_are_scipys_26_connected_labels_number_for_number(
    shape: tuple[int, int, int], density: float
) -> None:
    """The grid's labels come from cc3d (5-6x faster): the same components, numbered in the same order, as
    `ndimage.label` with a 3x3x3 structure, on a slice of a grid too (the flight band's layers)."""
    from swarm.explore.frontiers import _label_26

    mask = np.random.default_rng(6).random(shape) < density
    expected, _ = ndimage.label(mask, structure=np.ones((3, 3, 3), dtype=bool))
    assert np.array_equal(_label_26(mask), expected)
    assert np.array_equal(_label_26(mask[:, :, 1:-1]), ndimage.label(mask[:, :, 1:-1], structure=np.ones((3,) * 3))[0])


@pytest.mark.parametrize("f", [1, 2, 3])
def test_coarsening_keeps_a_cell_with_any_fine_cell_set(f: int) -> None:
    from swarm.explore.frontiers import _coarsen

    fine = np.random.default_rng(4).random((6 * f, 4 * f, 5 * f)) < 0.02
    expected = fine.reshape(6, f, 4, f, 5, f).any(axis=(1, 3, 5))
    assert np.array_equal(_coarsen(fine, f), expected)


def test_a_drone_shut_in_a_pocket_of_its_map_is_told_so_and_where_the_open_space_is() -> None:
    """A planner started in a pocket fails after a few cells ("unreachable from start, 2-4 cells searched"), and
    every frontier would be given up from there: the drone must know it is in one, and where to get out."""
    states = room_states(known_to_x=8.0)
    set_states(states, (4.6, 2.0, 0.8), (6.8, 4.2, 2.2), OCCUPIED)  # a hollow block round (5.7, 3.1, 1.5)
    set_states(states, (4.8, 2.2, 1.0), (6.6, 4.0, 2.0), FREE)  # ... whose inside holds a few safe cells
    inside = (5.7, 3.1, 1.5)
    assert _grid(states).escape(inside) is None  # walled in: no straight way out through known free space
    set_states(states, (6.6, 3.0, 1.4), (6.8, 3.2, 1.6), FREE)  # a slot in its east wall, too narrow to be safe
    grid = _grid(states)
    assert grid.reachable(inside).any() and grid.in_pocket(inside)
    assert not grid.in_pocket(LEFT)
    out = grid.escape(inside)
    assert out is not None and not grid.in_pocket(out) and grid.planning_grid.is_free(out)
    assert out[0] > 6.8  # out through the slot
    assert grid.reachable(out)[_cell(LEFT)]  # the room's space, not another pocket
    assert grid.escape((4.1, 3.0, -5.0)) is None  # nothing open within ESCAPE_RADIUS_M
    assert grid.connected(out, LEFT) and grid.connected(LEFT, out)
    assert not grid.connected(inside, LEFT) and not grid.connected(inside, (4.1, 3.0, -5.0))  # none near the last


def test_a_take_off_spot_under_the_cone_the_camera_never_saw_is_a_pocket_with_a_way_out_under_no_obstacle() -> None:
    """A camera that looks ahead never sees the space right above it: after take-off the cells round the drone
    have unknown space where the airframe would be, so the drone's safe space is a pocket (gen:11, one drone,
    waited there for the whole flight). It gets out along known free cells; the unknown above is allowed, an
    obstacle where the top of the airframe would pass is not."""
    settings = ExploreSettings()
    here, open_space = (2.0, 3.0, 1.3), (6.0, 3.0, 1.3)
    states = room_states(known_to_x=8.0)
    set_states(states, (0.2, 0.2, 1.5), (3.79, 5.8, 2.8), UNKNOWN)  # unseen above the drone, wall to wall in y
    grid = _grid(states, settings)
    assert grid.in_pocket(here) and not grid.in_pocket(open_space)
    out = grid.escape(here)
    assert out is not None and not grid.in_pocket(out) and grid.reachable(out)[_cell(open_space)]
    # a beam across the way out, above the drone's own height but low enough to meet any way out's airframe top
    set_states(states, (3.0, 0.2, 1.41), (3.19, 5.8, 2.8), OCCUPIED)
    assert _grid(states, settings).escape(here) is None
