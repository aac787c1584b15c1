"""Travel distances through the safe cells (`swarm.explore.travel`, `ExplorationGrid.travel_distances`)."""

import math

import numpy as np
import pytest

from swarm.config import ExploreSettings
from swarm.explore.frontiers import ExplorationGrid
from swarm.explore.travel import FAR_GOALS, TravelGraph
from swarm.patches.fused import FREE, OCCUPIED
from tests.explore.synthetic import set_states, state_grid

RES = 0.2


def _two_rooms() -> np.ndarray:
    """A 10 x 6 x 2.4 m box split by a wall at x = 5.0-5.2 m with a 1.2 m door at its north end (y 4.6-5.8)."""
    states = state_grid((10.0, 6.0, 2.4), FREE)
    set_states(states, (5.0, 0.0, 0.0), (5.19, 4.59, 2.39), OCCUPIED)
    return states


def test_the_way_round_a_wall_is_longer_than_the_line_through_it() -> None:
    safe = np.ones((50, 30, 12), dtype=bool)
    # a wall at x = 5.0-5.2 m and its clearance (x 4.6-5.6 m not safe), open at its north end (y >= 5.2 m)
    safe[23:28, :26, :] = False
    graph = TravelGraph(safe, np.zeros(3), RES)
    west, east = np.array([[4.0, 1.0, 1.0]]), np.array([[6.4, 1.0, 1.0], [4.0, 5.0, 1.0]])
    d = graph.distances(west, east)
    # to the east: up the wall to the gap and back down, about 2 x 4.3 m, not 2.4 m
    assert d[0, 0] > 8.0
    assert d[0, 0] < 10.5
    # along the same side: about the straight line (26-connected steps overestimate by well under 10 %)
    assert d[0, 1] == pytest.approx(4.0, rel=0.1)
    assert d[0, 1] >= 4.0


def test_a_start_or_goal_the_graph_does_not_hold_gets_the_straight_line() -> None:
    safe = np.ones((20, 20, 10), dtype=bool)
    safe[10:, :, :] = False  # nothing safe east of x = 2 m
    graph = TravelGraph(safe, np.zeros(3), RES)
    starts = np.array([[1.0, 1.0, 1.0], [3.0, 1.0, 1.0], [-5.0, 0.0, 0.0]])  # in, not safe, off the grid
    goals = np.array([[1.0, 3.0, 1.0], [3.0, 3.0, 1.0]])
    d = graph.distances(starts, goals)
    straight = np.linalg.norm(starts[:, None] - goals[None], axis=2)
    assert d[0, 0] == pytest.approx(2.0, rel=0.1)
    assert np.allclose(d[0, 1], straight[0, 1])  # the goal is in no safe cell
    assert np.allclose(d[1:], straight[1:])
    # two components: no way between them, the straight line
    safe[:, 8:12, :] = False
    split = TravelGraph(safe[:10], np.zeros(3), RES)
    assert split.distances(starts[:1], np.array([[1.0, 3.0, 1.0]]))[0, 0] == pytest.approx(2.0)


def test_the_merge_does_not_open_a_wall_between_safe_cells() -> None:
    # The map's states, a one-cell wall: the safe cells stop 0.4 m short of it on each side, so no coarse cell,
    # nor two neighbouring ones, hold safe cells of both sides, and the way is round by the door.
    states = _two_rooms()
    grid = ExplorationGrid.from_states(
        (0.0, 0.0, 0.0), RES, states, ExploreSettings(body_height_m=0.0, min_altitude_m=0.5), 0.0, 2.4
    )
    d = grid.travel_distances(np.array([[4.5, 1.0, 1.1]]), np.array([[5.7, 1.0, 1.1]]))
    assert d[0, 0] > 2 * 3.6  # round by the door, whose near edge is 3.6 m north
    assert math.isfinite(d[0, 0])


def test_viewpoints_on_two_sides_of_a_wall_are_as_far_apart_as_the_way_round_in_either_direction() -> None:
    """`travel_between`, the leader's distances among viewpoints for its tours."""
    grid = ExplorationGrid.from_states(
        (0.0, 0.0, 0.0), RES, _two_rooms(), ExploreSettings(body_height_m=0.0, min_altitude_m=0.5), 0.0, 2.4
    )
    views = np.array([[4.5, 1.0, 1.1], [5.7, 1.0, 1.1], [3.0, 1.0, 1.1]])
    d = grid.travel_between(views)
    assert d.shape == (3, 3) and np.allclose(np.diag(d), 0.0)
    assert d[0, 1] > 2 * 3.6 and d[1, 0] > 2 * 3.6  # round by the door
    assert d[0, 2] == pytest.approx(1.5, rel=0.15)


def test_a_drone_beside_a_wall_starts_from_the_nearest_safe_cell() -> None:
    states = _two_rooms()
    grid = ExplorationGrid.from_states(
        (0.0, 0.0, 0.0), RES, states, ExploreSettings(body_height_m=0.0, min_altitude_m=0.5), 0.0, 2.4
    )
    beside = np.array([[4.9, 1.0, 1.1]])  # 0.1 m from the wall: its cell is blocked by the clearance
    assert not grid.planning_grid.is_free(tuple(beside[0]))
    d = grid.travel_distances(beside, np.array([[5.7, 1.0, 1.1], [4.0, 1.0, 1.1]]))
    assert d[0, 0] > 2 * 3.6
    assert d[0, 1] == pytest.approx(0.9, abs=0.5)


def test_beyond_the_search_limit_a_goal_gets_the_straight_line_but_no_less_than_the_limit() -> None:
    safe = np.ones((50, 30, 12), dtype=bool)
    safe[23:28, :26, :] = False  # the wall of the first test: 2.4 m east by the line, about 9 m by the gap
    graph = TravelGraph(safe, np.zeros(3), RES)
    west, goals = np.array([[4.0, 1.0, 1.0]]), np.array([[6.4, 1.0, 1.0], [4.0, 3.0, 1.0]])
    near, unlimited = graph.distances(west, goals, limit_m=5.0), graph.distances(west, goals)
    assert unlimited[0, 0] > 8.0
    assert near[0, 0] == pytest.approx(5.0, abs=0.01)  # not reached within 5 m: at least the limit
    assert near[0, 1] == pytest.approx(unlimited[0, 1])  # reached: the same way
    # another component stays the straight line, limit or not
    split = safe.copy()
    split[:, 12:16, :] = False
    apart = TravelGraph(split, np.zeros(3), RES).distances(west, np.array([[4.0, 4.0, 1.0]]), limit_m=1.0)
    assert apart[0, 0] == pytest.approx(3.0)


def test_a_goal_beyond_the_search_from_every_start_is_searched_all_the_way_for_the_nearest_few() -> None:
    safe = np.ones((50, 30, 12), dtype=bool)
    safe[23:28, :26, :] = False  # a wall with a gap at its north end
    graph = TravelGraph(safe, np.zeros(3), RES)
    starts = np.array([[4.0, 1.0, 1.0], [3.0, 1.0, 1.0]])
    # east of the wall, every one beyond 5 m from both starts by the gap; the farther by the line come last
    goals = np.array([[6.4 + 0.4 * i, 1.0, 1.0] for i in range(FAR_GOALS + 1)])
    unlimited = graph.distances(starts, goals)
    assert (unlimited > 5.0).all()
    near = graph.distances(starts, goals, limit_m=5.0)
    assert near[:, :FAR_GOALS] == pytest.approx(unlimited[:, :FAR_GOALS])  # the nearest few: the whole way
    last = near[:, FAR_GOALS]  # past FAR_GOALS: ranked by the line, still about the limit
    assert 5.0 <= last[0] < last[1] < 5.0 + 0.01


def test_between_storeys_the_drone_on_the_goals_storey_ranks_first_though_the_other_is_nearer_by_the_line() -> None:
    """A drone straight above a leftover, 2.4 m from it by the line, is 20 m from it by the stairwell."""
    safe = np.ones((80, 30, 22), dtype=bool)  # 16 x 6 m, two storeys: floors 0-2 m and 2.4-4.4 m
    safe[:, :, 10:12] = False  # the slab
    safe[0:5, :, 10:12] = True  # the stairwell at the west end, x 0-1 m
    graph = TravelGraph(safe, np.zeros(3), RES)
    goal = np.array([[12.0, 3.0, 1.0]])
    upstairs, downstairs = [12.0, 3.0, 3.4], [1.0, 3.0, 1.0]  # 2.4 m and 11 m from it by the line
    d = graph.distances(np.array([upstairs, downstairs]), goal, limit_m=5.0)
    assert d[1, 0] < d[0, 0]
    assert d[0, 0] > 20.0 and d[1, 0] == pytest.approx(11.0, rel=0.1)


def _random_safe(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    safe = rng.random((24, 18, 8)) < 0.035  # a quarter of the coarse cells passable: many components
    safe[:, 8:10, :] = False  # and a wall of whole coarse cells across the grid
    return safe


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_components_are_the_graphs_own(seed: int) -> None:
    """The components come from the coarse cells (cc3d), not from the graph: the same partition of the nodes."""
    from scipy.sparse.csgraph import connected_components

    graph = TravelGraph(_random_safe(seed), np.zeros(3), RES)
    _, expected = connected_components(graph._graph, directed=False)
    ours = graph._component
    assert len(ours) == graph.nodes
    pairs = set(zip(ours.tolist(), expected.tolist()))
    assert len(pairs) == len(set(ours.tolist())) == len(set(expected.tolist()))  # one-to-one: the same partition
    assert len(pairs) > 1


def test_a_search_asked_again_is_kept_and_gives_what_a_fresh_graph_gives(monkeypatch: pytest.MonkeyPatch) -> None:
    import swarm.explore.travel as travel

    safe = _random_safe(3)
    searched: list[int] = []
    real = travel.dijkstra

    def counting(*args: object, **kwargs: object) -> np.ndarray:
        searched.append(len(kwargs["indices"]))  # type: ignore[arg-type]
        return real(*args, **kwargs)  # type: ignore[no-any-return]

    monkeypatch.setattr(travel, "dijkstra", counting)
    graph = TravelGraph(safe, np.zeros(3), RES)
    nodes = np.flatnonzero(graph._coarse.ravel())
    cells = np.argwhere(graph._coarse)
    points = (cells[:: max(1, len(cells) // 9)][:9] + 0.5) * graph.cell
    first = graph.distances(points[:4], points, limit_m=1.5)
    assert sum(searched) > 0
    searched.clear()
    again = graph.distances(points[:4], points, limit_m=1.5)
    assert searched == []  # every row kept
    assert np.array_equal(first, again)
    fresh = TravelGraph(safe, np.zeros(3), RES).distances(points[:4], points, limit_m=1.5)
    assert np.array_equal(first, fresh)
    # another limit is another search; rows are kept up to ROWS_KEPT, the most recently used
    graph.distances(points[:2], points, limit_m=3.0)
    assert searched
    for start in points:
        graph.distances(start[None, :], points[:1])
    assert len(graph._rows) <= travel.ROWS_KEPT
    assert len(nodes) == graph.nodes
