"""The leader's tour assignment (`swarm.roles.tours`): candidates divided by position, each member sent to the first
of its own tour."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.config import Vec3
from swarm.roles.assignment import Candidate, assign_targets
from swarm.roles.tours import _two_opt, assign_tours

pytestmark = pytest.mark.unit


def _c(x: float, y: float = 0.0, gain: float = 5.0, owner: int = 1) -> Candidate:
    return Candidate((x, y, 1.5), (x, y + 0.5, 1.5), gain, owner)


def _at(x: float, y: float = 0.0) -> Vec3:
    return (x, y, 1.5)


def _x(choice: dict[int, Candidate | None]) -> dict[int, float | None]:
    return {k: None if c is None else c.viewpoint[0] for k, c in choice.items()}


def test_a_drone_takes_the_small_candidates_beside_it_before_the_large_one_farther_on() -> None:
    """The leftovers next to a drone are on its way; by utility it leaves them for a large gain and comes back."""
    candidates = [_c(-1.0, gain=2.5), _c(-2.0, gain=2.5), _c(8.0, gain=60.0)]
    assert _x(assign_targets(candidates, {1: _at(0.0)}, lam=0.2, sigma=6.0)) == {1: 8.0}
    assert _x(assign_tours(candidates, {1: _at(0.0)})) == {1: -1.0}


def test_two_drones_at_the_two_ends_of_a_corridor_each_work_their_own_end() -> None:
    candidates = [_c(x) for x in (1.0, 2.0, 3.0, 7.0, 8.0, 9.0)]
    assert _x(assign_tours(candidates, {1: _at(0.0), 2: _at(10.0)})) == {1: 1.0, 2: 9.0}


def test_an_idle_drone_takes_the_candidate_it_reaches_before_the_owner_along_its_tour() -> None:
    """Drone 1 is nearer to all six, but its tour reaches x = -3.2 after 9.2 m; drone 2 is 4.8 m from it."""
    candidates = [_c(x) for x in (1.0, 2.0, 3.0, -1.2, -2.2, -3.2)]
    assert _x(assign_tours(candidates, {1: _at(0.0)})) == {1: 1.0}
    assert _x(assign_tours(candidates, {1: _at(0.0), 2: _at(-8.0)})) == {1: 1.0, 2: -3.2}


def test_an_idle_drone_does_not_chase_what_the_owner_reaches_first() -> None:
    candidates = [_c(x) for x in (2.0, 4.0, 6.0)]
    assert _x(assign_tours(candidates, {1: _at(0.0), 2: _at(-5.0)})) == {1: 2.0, 2: None}


def test_a_drone_keeps_its_current_target_against_a_slightly_better_tour() -> None:
    candidates = [_c(2.0), _c(-2.2)]
    assert _x(assign_tours(candidates, {1: _at(0.0)})) == {1: 2.0}
    kept = assign_tours(candidates, {1: _at(0.0)}, current={1: _at(-2.2)}, current_bonus=3.0)
    assert _x(kept) == {1: -2.2}
    far = [_c(2.0), _c(-9.0)]  # a U-turn is still made when the current target is far the wrong way
    assert _x(assign_tours(far, {1: _at(0.0)}, current={1: _at(-9.0)}, current_bonus=3.0)) == {1: 2.0}


def test_a_candidate_one_member_cannot_reach_goes_to_another_and_weak_ones_to_nobody() -> None:
    candidates = [_c(1.0), _c(5.0, gain=0.5)]
    choice = assign_tours(candidates, {1: _at(0.0), 2: _at(9.0)}, unreachable={1: [_at(1.0)]}, min_gain=1.0)
    assert _x(choice) == {1: None, 2: 1.0}


def test_tours_follow_the_given_distances_not_the_straight_line() -> None:
    """A wall between the drone and x = 1: by the way round, x = -2 is nearer."""

    def around(starts: np.ndarray, goals: np.ndarray) -> np.ndarray:
        line = np.linalg.norm(np.reshape(starts, (-1, 1, 3)) - np.reshape(goals, (1, -1, 3)), axis=2)
        walled = (np.reshape(goals, (1, -1, 3))[..., 0] > 0.5) & (np.reshape(starts, (-1, 1, 3))[..., 0] < 0.5)
        return np.where(walled, line + 20.0, line)

    candidates = [_c(1.0), _c(-2.0)]
    assert _x(assign_tours(candidates, {1: _at(0.0)}, distances=around)) == {1: -2.0}


def test_two_opt_uncrosses_a_tour() -> None:
    points = np.array([[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [2.0, 1.0], [2.0, 0.0]])
    among = np.linalg.norm(points[:, None] - points[None], axis=2)
    crossed = [0, 1, 2, 3, 4]  # 0 -> (1,1) -> (1,0) -> (2,1) -> (2,0): a zig-zag with two crossings of length
    better = _two_opt(crossed, None, among)

    def length(order: list[int]) -> float:
        return float(sum(among[a, b] for a, b in zip(order, order[1:])))

    assert better[0] == 0 and sorted(better) == crossed
    assert length(better) < length(crossed) - 0.1


def test_a_tour_that_ends_at_home_leaves_the_candidates_on_the_way_home_for_last() -> None:
    """Home is 10 m west: east first and back through the west one, not west first and east again."""
    candidates = [_c(-2.8), _c(3.0)]
    assert _x(assign_tours(candidates, {1: _at(0.0)})) == {1: -2.8}
    assert _x(assign_tours(candidates, {1: _at(0.0)}, homes={1: _at(-10.0)})) == {1: 3.0}


def test_a_leftover_on_one_drones_way_home_is_that_drones_though_another_is_nearer() -> None:
    """Drone 1 flies home 20 m west past the leftover (4 m off); drone 2, 3 m from it, is 3 m from its own home."""
    leftover = [_c(-4.0)]
    positions = {1: _at(0.0), 2: _at(-4.0, 3.0)}
    assert _x(assign_tours(leftover, positions)) == {1: None, 2: -4.0}
    homes = {1: _at(-20.0), 2: _at(-4.0, 6.0)}
    assert _x(assign_tours(leftover, positions, homes=homes)) == {1: -4.0, 2: None}
