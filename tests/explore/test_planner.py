import numpy as np
import pytest

from swarm.config import Vec3
from swarm.explore.grid import OccupancyGrid
from swarm.explore.planner import NoPathError, path_is_free, path_length, plan_path, plan_path_around
from swarm.explore.travel import TravelGraph
from tests.explore.synthetic import clearance, densify, empty_grid, fill, office_grid, room_with_wall

DRONE_RADIUS = 0.3
WALL_X = (4.0, 4.2)  # room_with_wall's wall cell spans x 4.0..4.2
DOOR_Y = (2.4, 3.6)


def _assert_collision_free(path: list[Vec3], inflated: OccupancyGrid, raw: OccupancyGrid | None = None) -> None:
    """Every segment is free on the inflated grid and, when `raw` is given, keeps DRONE_RADIUS from it."""
    assert all(inflated.segment_is_free(a, b) for a, b in zip(path[:-1], path[1:]))
    if raw is not None:
        assert clearance(raw, densify(path, 0.02)).min() >= DRONE_RADIUS - 1e-9


def test_straight_corridor_gives_two_waypoints() -> None:
    grid = empty_grid((10.0, 3.0, 3.0))
    fill(grid, (0, 0, 0), (10, 0.9, 3))
    fill(grid, (0, 2.1, 0), (10, 3, 3))
    inflated = grid.inflate(DRONE_RADIUS)
    start, goal = (0.5, 1.5, 1.5), (9.5, 1.5, 1.5)
    path = plan_path(inflated, start, goal)
    assert path == [start, goal]
    assert path_length(path) == pytest.approx(9.0)


def test_path_goes_through_the_door_and_keeps_clear_of_the_wall() -> None:
    raw = room_with_wall(door_open=True)
    inflated = raw.inflate(DRONE_RADIUS)
    start, goal = (1.0, 0.6, 1.0), (7.0, 5.4, 1.0)
    path = plan_path(inflated, start, goal)

    assert path[0] == start and path[-1] == goal
    assert 3 <= len(path) <= 6
    _assert_collision_free(path, inflated, raw)
    points = densify(path, 0.02)
    in_wall = points[(points[:, 0] >= WALL_X[0]) & (points[:, 0] <= WALL_X[1])]
    assert len(in_wall) > 0
    assert np.all((in_wall[:, 1] > DOOR_Y[0]) & (in_wall[:, 1] < DOOR_Y[1]) & (in_wall[:, 2] < 2.0))
    assert path_length(path) < 1.1 * (np.hypot(3.0, 3.0 - 0.6) + np.hypot(3.0, 5.4 - 3.0))


def test_closed_door_means_no_path() -> None:
    inflated = room_with_wall(door_open=False).inflate(DRONE_RADIUS)
    with pytest.raises(NoPathError, match="unreachable"):
        plan_path(inflated, (1.0, 0.6, 1.0), (7.0, 5.4, 1.0))


def test_a_door_narrower_than_the_drone_is_closed() -> None:
    raw = room_with_wall(door_open=False)
    fill(raw, (4.0, 2.8, 0.0), (4.19, 3.2, 2.0), value=False)  # 0.4 m wide, for a drone 0.6 m across
    with pytest.raises(NoPathError):
        plan_path(raw.inflate(DRONE_RADIUS), (1.0, 0.6, 1.0), (7.0, 5.4, 1.0))


def test_start_in_an_inflated_cell_is_snapped_to_free_space() -> None:
    raw = room_with_wall()
    inflated = raw.inflate(DRONE_RADIUS)
    start = (3.75, 1.0, 1.0)  # 0.25 m from the wall: inside the inflated margin, within snapping reach
    assert not inflated.is_free(start)
    path = plan_path(inflated, start, (7.0, 5.4, 1.0))
    assert path[0] != start
    assert inflated.is_free(path[0])
    assert np.linalg.norm(np.subtract(path[0], start)) <= 2 * inflated.resolution
    _assert_collision_free(path, inflated)


def test_start_deep_inside_an_obstacle_is_rejected() -> None:
    raw = fill(room_with_wall(), (0.0, 0.0, 0.0), (2.0, 2.0, 3.0))
    with pytest.raises(NoPathError, match="start .* blocked"):
        plan_path(raw.inflate(DRONE_RADIUS), (1.0, 1.0, 1.0), (7.0, 5.4, 1.0))


def test_goal_blocked_or_outside_the_grid_is_rejected() -> None:
    inflated = room_with_wall().inflate(DRONE_RADIUS)
    with pytest.raises(NoPathError, match="goal .* blocked"):
        plan_path(inflated, (1.0, 1.0, 1.0), (4.1, 1.0, 2.5))
    with pytest.raises(NoPathError, match="goal .* outside the grid"):
        plan_path(inflated, (1.0, 1.0, 1.0), (9.0, 1.0, 1.0))
    with pytest.raises(NoPathError, match="start .* outside the grid"):
        plan_path(inflated, (1.0, 1.0, -0.5), (7.0, 1.0, 1.0))


def _wall_with_high_gap_and_low_door() -> tuple[OccupancyGrid, OccupancyGrid]:
    """Wall at x = 4 m from floor to 2 m with open space above it, and a door at y 4.4..5.6 m below 1.2 m."""
    raw = fill(empty_grid((8.0, 6.0, 3.0)), (4.0, 0.0, 0.0), (4.19, 6.0, 2.0))
    fill(raw, (4.0, 4.4, 0.0), (4.19, 5.6, 1.2), value=False)
    return raw, raw.inflate(DRONE_RADIUS)


def test_without_z_limits_the_path_flies_over_the_wall() -> None:
    raw, inflated = _wall_with_high_gap_and_low_door()
    path = plan_path(inflated, (1.0, 0.6, 0.7), (7.0, 0.6, 0.7))
    assert max(p[2] for p in path) > 2.0
    _assert_collision_free(path, inflated, raw)


def test_z_limits_keep_the_path_in_the_altitude_band() -> None:
    raw, inflated = _wall_with_high_gap_and_low_door()
    path = plan_path(inflated, (1.0, 0.6, 0.7), (7.0, 0.6, 0.7), z_limits=(0.5, 0.9))
    points = densify(path, 0.02)
    assert points[:, 2].min() >= 0.5 - 1e-9 and points[:, 2].max() <= 0.9 + 1e-9
    assert np.any((points[:, 1] > 4.4) & (points[:, 1] < 5.6) & (np.abs(points[:, 0] - 4.1) < 0.1))
    _assert_collision_free(path, inflated, raw)


def test_single_layer_z_limits_plan_in_that_layer() -> None:
    raw, inflated = _wall_with_high_gap_and_low_door()
    # 0.75 is no cell centre (they are at 0.1 + 0.2 k): the layer containing it, centred at 0.7, is used.
    path = plan_path(inflated, (1.0, 0.6, 0.7), (7.0, 0.6, 0.7), z_limits=(0.75, 0.75))
    assert [p[2] for p in path] == pytest.approx([0.7] * len(path))
    _assert_collision_free(path, inflated, raw)
    # A band one cell wide whose ends are both layer centres (0.5 and 0.7) is still a single layer.
    path = plan_path(inflated, (1.0, 0.6, 0.6), (7.0, 0.6, 0.6), z_limits=(0.5, 0.7))
    altitudes = {round(p[2], 6) for p in path[1:-1]}
    assert len(altitudes) == 1 and altitudes <= {0.5, 0.7}
    with pytest.raises(NoPathError, match="z_limits"):
        plan_path(inflated, (1.0, 0.6, 0.7), (7.0, 0.6, 0.7), z_limits=(2.5, 2.5))  # start is 9 layers below


def test_unknown_cells_are_obstacles_only_when_asked() -> None:
    raw = room_with_wall(door_open=True)
    raw.unknown = np.zeros(raw.shape, dtype=bool)
    raw.unknown[20:21, 12:18, :10] = True  # the doorway has not been observed
    start, goal = (1.0, 0.6, 1.0), (7.0, 5.4, 1.0)
    path = plan_path(raw.inflate(DRONE_RADIUS, unknown_is_occupied=False), start, goal)
    _assert_collision_free(path, raw.inflate(DRONE_RADIUS), raw)
    with pytest.raises(NoPathError, match="unreachable"):
        plan_path(raw.inflate(DRONE_RADIUS, unknown_is_occupied=True), start, goal)


def test_path_is_free_detects_a_map_change_for_replanning() -> None:
    start, goal = (1.0, 0.6, 1.0), (7.0, 5.4, 1.0)
    inflated = room_with_wall().inflate(DRONE_RADIUS)
    path = plan_path(inflated, start, goal)
    assert path_is_free(inflated, path)

    updated_raw = fill(room_with_wall(), (6.0, 4.0, 0.0), (6.6, 6.0, 3.0))  # a new obstacle on the last leg
    updated = updated_raw.inflate(DRONE_RADIUS)
    assert not path_is_free(updated, path)
    replanned = plan_path(updated, start, goal)
    _assert_collision_free(replanned, updated, updated_raw)


def test_search_budget_and_trivial_paths() -> None:
    inflated = room_with_wall().inflate(DRONE_RADIUS)
    with pytest.raises(NoPathError, match="gave up after 10 expansions"):
        plan_path(inflated, (1.0, 0.6, 1.0), (7.0, 5.4, 1.0), max_expansions=10)
    assert plan_path(inflated, (1.0, 1.0, 1.0), (1.0, 1.0, 1.0)) == [(1.0, 1.0, 1.0), (1.0, 1.0, 1.0)]
    assert plan_path(inflated, (1.0, 1.0, 1.0), (1.05, 1.02, 1.0)) == [(1.0, 1.0, 1.0), (1.05, 1.02, 1.0)]


def test_path_length() -> None:
    assert path_length([(0.0, 0.0, 0.0), (3.0, 4.0, 0.0), (3.0, 4.0, 2.0)]) == pytest.approx(7.0)
    assert path_length([(1.0, 2.0, 3.0)]) == 0.0


def test_office_far_corner_through_two_doors() -> None:
    raw = office_grid()
    inflated = raw.inflate(0.25)
    path = plan_path(inflated, (1.0, 1.0, 1.5), (29.0, 19.0, 1.5))
    assert path[0] == (1.0, 1.0, 1.5) and path[-1] == (29.0, 19.0, 1.5)
    _assert_collision_free(path, inflated)
    assert path_length(path) < 45.0


def _with_roomy(raw: OccupancyGrid, clearance_m: float, roomy_m: float) -> OccupancyGrid:
    planning = raw.inflate(clearance_m)
    return OccupancyGrid(planning.origin, planning.resolution, planning.occupied, roomy=~raw.inflate(roomy_m).occupied)


def test_a_path_round_a_wall_end_keeps_the_wider_clearance_where_there_is_room() -> None:
    raw = empty_grid((8.0, 6.0, 3.0), resolution=0.1)
    fill(raw, (4.0, 3.0, 0.0), (4.19, 6.0, 3.0))  # a wall stub from y = 6 down to its end at y = 3
    start, goal = (2.0, 4.5, 1.5), (6.0, 4.5, 1.5)

    taut = plan_path(raw.inflate(0.25), start, goal)
    assert clearance(raw, densify(taut, 0.02)).min() < 0.35  # shortcutting pulls it against the wall end

    path = plan_path(_with_roomy(raw, 0.25, 0.45), start, goal)
    assert path[0] == start and path[-1] == goal
    assert clearance(raw, densify(path, 0.02)).min() >= 0.45 - 1e-9
    assert path_length(path) < 1.15 * path_length(taut)


def test_a_path_across_a_narrow_place_is_pulled_straight_not_left_a_staircase_of_45_degree_steps() -> None:
    raw = empty_grid((8.0, 2.4, 3.0))
    fill(raw, (0.0, 0.0, 0.0), (8.0, 0.19, 3.0))
    fill(raw, (0.0, 1.6, 0.0), (8.0, 2.4, 3.0))  # a corridor 1.4 m wide: nowhere 0.9 m clear of both walls
    grid = _with_roomy(raw, 0.25, 0.9)
    assert not grid.roomy.any()
    start, goal = (0.5, 0.7, 1.5), (7.5, 1.1, 1.5)
    path = plan_path(grid, start, goal)
    # every cell costs the same here: A*'s own path climbs to y 1.1 in 45-degree steps somewhere on the way
    assert path[0] == start and path[-1] == goal and len(path) <= 3
    legs = np.diff(np.array(path), axis=0)
    turns = [np.degrees(np.arccos(a @ b / np.linalg.norm(a) / np.linalg.norm(b))) for a, b in zip(legs, legs[1:])]
    assert max(turns, default=0.0) < 10.0
    _assert_collision_free(path, grid)
    assert clearance(raw, densify(path, 0.02)).min() >= 0.25 - 1e-9


def test_a_door_too_narrow_for_the_wider_clearance_is_flown_at_the_minimum() -> None:
    raw = room_with_wall(door_open=True)  # 1.2 m: no cell of it is 0.45 m clear of both jambs
    grid = _with_roomy(raw, 0.25, 0.45)
    assert not grid.roomy[20:22].any()  # the wall's and the door's cells, x 4.0..4.4
    path = plan_path(grid, (1.0, 0.6, 1.0), (7.0, 5.4, 1.0))
    _assert_collision_free(path, grid)
    assert clearance(raw, densify(path, 0.02)).min() >= 0.25 - 1e-9


def test_z_limits_keep_the_roomy_cells_of_their_layers() -> None:
    raw = empty_grid((8.0, 6.0, 3.0))
    fill(raw, (4.0, 3.0, 0.0), (4.19, 6.0, 3.0))
    grid = _with_roomy(raw, 0.25, 0.45)
    path = plan_path(grid, (2.0, 4.5, 1.5), (6.0, 4.5, 1.5), z_limits=(1.5, 1.5))
    assert [p[2] for p in path] == pytest.approx([1.5] * len(path))
    assert clearance(raw, densify(path, 0.02)).min() >= 0.45 - 1e-9


def _distance_to_path(path: list[Vec3], point: Vec3) -> float:
    return float(np.linalg.norm(densify(path, 0.02) - np.asarray(point), axis=1).min())


def test_a_path_round_a_parked_drone_keeps_its_clearance_where_the_room_allows() -> None:
    """A 4 m wide hall, a drone hovering on the straight way: the plain path passes through it, the path round it
    keeps the clearance (and stays free of the walls)."""
    grid = empty_grid((10.0, 4.0, 3.0))
    inflated = grid.inflate(DRONE_RADIUS)
    start, goal, parked = (0.5, 2.0, 1.5), (9.5, 2.0, 1.5), (5.0, 2.0, 1.5)
    assert _distance_to_path(plan_path(inflated, start, goal), parked) < 0.05
    path = plan_path_around(inflated, start, goal, parked, 0.6)
    assert path[0] == start and path[-1] == goal
    assert _distance_to_path(path, parked) >= 0.6 - 1e-9
    _assert_collision_free(path, inflated)


def test_no_way_round_a_drone_parked_in_a_doorway() -> None:
    raw = fill(room_with_wall(door_open=True), (0.0, 0.0, 0.0), (8.0, 6.0, 0.1))  # a floor: no way under it
    inflated = raw.inflate(DRONE_RADIUS)
    in_the_door = (4.1, 3.0, 1.0)
    assert plan_path(inflated, (1.0, 0.6, 1.0), (7.0, 5.4, 1.0))  # through the door when it is not there
    with pytest.raises(NoPathError):
        plan_path_around(inflated, (1.0, 0.6, 1.0), (7.0, 5.4, 1.0), in_the_door, 0.6)


def test_the_ball_round_a_parked_drone_never_swallows_the_start() -> None:
    """Starting 0.5 m from the drone, the path leaves from the start and goes round at no less than it began."""
    grid = empty_grid((10.0, 4.0, 3.0))
    inflated = grid.inflate(DRONE_RADIUS)
    start, parked = (4.5, 2.0, 1.5), (5.0, 2.0, 1.5)
    path = plan_path_around(inflated, start, (9.5, 2.0, 1.5), parked, 0.6)
    assert path[0] == start
    assert _distance_to_path(path[1:] if len(path) > 2 else path, parked) > 0.5 - np.sqrt(3) * 0.2 - 1e-9
    with pytest.raises(NoPathError, match="too close"):
        plan_path_around(inflated, (4.9, 2.0, 1.5), (9.5, 2.0, 1.5), parked, 0.6)


def test_cells_near_a_ball_are_blocked_and_the_rest_kept() -> None:
    grid = empty_grid((4.0, 4.0, 2.0))
    fill(grid, (0.0, 0.0, 0.0), (0.2, 0.2, 0.2))
    blocked = grid.with_balls_blocked([(2.0, 2.0, 1.0)], 0.5)
    centres = blocked.centre_of(np.argwhere(blocked.occupied))
    distances = np.linalg.norm(centres - np.array([2.0, 2.0, 1.0]), axis=1)
    assert blocked.occupied[0, 0, 0] and grid.occupied.sum() == 1  # the original is untouched
    assert (distances[distances > 1.0]).size == 1  # only the old obstacle lies far away
    cells = np.argwhere(np.ones(grid.shape, dtype=bool))
    inside = cells[np.linalg.norm(grid.centre_of(cells) - np.array([2.0, 2.0, 1.0]), axis=1) < 0.5]
    assert len(inside) > 0 and blocked.occupied[tuple(inside.T)].all()


def _two_storeys() -> OccupancyGrid:
    """Two storeys of 16 x 10 m (floors 0-2 m and 2.4-4.4 m) joined by one stairwell at the west end; the goal
    is straight above the start, 11 m from the stairwell."""
    grid = empty_grid((16.0, 10.0, 4.4))
    fill(grid, (0.0, 0.0, 2.0), (16.0, 10.0, 2.4))  # the slab
    grid.occupied[0:5, 4:21, 10:12] = False  # the stairwell: x 0-1 m, y 0.8-4.2 m
    return grid


def test_a_path_led_by_the_travel_graph_finds_the_stairwell_the_straight_line_misses() -> None:
    raw = _two_storeys()
    inflated = raw.inflate(DRONE_RADIUS)
    start, goal = (12.0, 5.0, 1.0), (12.0, 5.0, 3.4)
    guide = TravelGraph(~inflated.occupied, inflated.origin, inflated.resolution)
    # Led by the straight line, A* fills the ground floor under the goal before it finds the stairwell.
    with pytest.raises(NoPathError, match="gave up"):
        plan_path(inflated, start, goal, max_expansions=20_000)
    guided = plan_path(inflated, start, goal, max_expansions=20_000, guide=lambda: guide)
    plain = plan_path(inflated, start, goal)
    assert guided[0] == start and guided[-1] == goal
    _assert_collision_free(guided, inflated, raw)
    assert path_length(guided) <= 1.05 * path_length(plain)  # about as short as the unguided search's
    level = (12.0, 1.0, 1.0)  # with z_limits the guide (of the whole grid) is not used
    assert plan_path(inflated, start, level, guide=lambda: guide, z_limits=(0.5, 1.5)) == plan_path(
        inflated, start, level, z_limits=(0.5, 1.5)
    )


def test_the_travel_graphs_distance_field_is_zero_at_the_goal_and_infinite_where_it_cannot_reach() -> None:
    raw = _two_storeys()
    inflated = raw.inflate(DRONE_RADIUS)
    guide = TravelGraph(~inflated.occupied, inflated.origin, inflated.resolution)
    field = guide.distance_field(np.array([12.0, 5.0, 3.4]), inflated.shape)
    assert field.shape == inflated.shape
    goal_cell = inflated.index_of((12.0, 5.0, 3.4))
    assert goal_cell is not None and field[goal_cell] == 0.0
    below = inflated.index_of((12.0, 5.0, 1.0))
    assert below is not None and 20.0 < field[below] < 30.0  # 11 m to the stairwell and back, not 2.4 m up
    inside_slab = inflated.index_of((8.0, 5.0, 2.2))
    assert inside_slab is not None and np.isinf(field[inside_slab])
    assert np.isinf(guide.distance_field(np.array([8.0, 5.0, 2.2]), inflated.shape)).all()  # goal in the slab


def _cells_cost(grid: OccupancyGrid, cells: list[np.ndarray]) -> float:
    """What `_astar` charges for a path of cells: each step's length times its cell's step cost."""
    from swarm.explore.planner import _step_cost_factors

    factors = _step_cost_factors(grid)
    steps = np.diff(np.array(cells), axis=0)
    into = np.array(cells[1:]) + 1  # the factors are padded by a cell
    return float(np.sum(np.linalg.norm(steps, axis=1) * factors[tuple(into.T)]))


def test_the_weighted_search_costs_at_most_its_weight_times_the_cheapest_path(monkeypatch: pytest.MonkeyPatch) -> None:
    """`HEURISTIC_WEIGHT`: across the office (doors, a corridor, roomy cells), each raw A* path of the weighted
    search costs no more than the weight times the exact search's (here they cost the same)."""
    import swarm.explore.planner as planner

    weight = planner.HEURISTIC_WEIGHT
    assert weight > 1.0
    grid = _with_roomy(office_grid(), 0.25, 0.45)
    trips = [
        ((2.0, 2.0, 1.5), (27.0, 17.0, 1.2)),
        ((3.0, 15.0, 1.0), (27.0, 3.0, 1.6)),
        ((10.0, 10.0, 1.5), (21.0, 4.0, 1.5)),
    ]
    ratios = []
    for start, goal in trips:
        a, b = np.array(start), np.array(goal)
        weighted = _cells_cost(grid, planner._astar(grid, a, b, 2_000_000))
        monkeypatch.setattr(planner, "HEURISTIC_WEIGHT", 1.0)
        exact = _cells_cost(grid, planner._astar(grid, a, b, 2_000_000))
        monkeypatch.setattr(planner, "HEURISTIC_WEIGHT", weight)
        assert exact <= weighted + 1e-9
        ratios.append(weighted / exact)
    assert max(ratios) <= weight + 1e-9
