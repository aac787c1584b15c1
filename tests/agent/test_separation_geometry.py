"""The geometry of the separation manoeuvre (`swarm.agent.flight`): refuges, distances to a way, where to rejoin.

Pure functions on positions; the flights that use them are in `test_separation.py`."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.agent.flight import (
    REFUGE_CLEAR_M,
    STEP_ASIDE_M,
    Neighbour,
    choose_refuge,
    closest_approach,
    distance_to_segment,
    distance_to_track,
    moves_clear_of,
    off_the_others_ways,
    refuge_candidates,
    refuge_in_the_way,
    resume_from,
)
from swarm.sim.worlds import load_world
from tests.agent.mesh_clearance import clear_in


def test_refuge_candidates_step_up_down_away_and_to_either_side_of_the_way() -> None:
    here = np.array([2.0, 2.0, 1.5])
    s = STEP_ASIDE_M
    peer = Neighbour(1, (1.0, 2.0, 1.5), (1.0, 0.0, 0.0))  # coming at us along +x
    offsets = [tuple(np.round(c - here, 6)) for c in refuge_candidates(here, peer)]
    near = [(0.0, 0.0, s), (0.0, 0.0, -s), (s, 0.0, 0.0), (0.0, s, 0.0), (0.0, -s, 0.0)]
    assert offsets == near + [tuple(2 * v for v in o) for o in near]
    below = Neighbour(1, (2.0, 2.0, 2.0), (0.0, 0.0, 0.0))  # above us: we step down first
    assert tuple(np.round(refuge_candidates(here, below)[0] - here, 6)) == (0.0, 0.0, -s)
    # a peer holding still on its way to a point beyond us: the sides of that segment, not of its velocity
    holding = Neighbour(1, (2.0, 1.0, 1.5), (0.0, 0.0, 0.0), heading_to=(2.0, 4.0, 1.5))
    sides = [tuple(np.round(c - here, 6)) for c in refuge_candidates(here, holding)][3:5]
    assert sorted(sides) == sorted([(s, 0.0, 0.0), (-s, 0.0, 0.0)])


def test_the_refuge_is_the_nearest_step_well_off_the_other_drones_way() -> None:
    here = np.array([2.0, 2.0, 1.5])
    s = STEP_ASIDE_M
    # A peer holding still, heading for a point just past us: stepping up by s is only s off its segment, enough
    # (>= REFUGE_CLEAR_M) when s is; a side step is as good, and up comes first.
    holding = Neighbour(1, (2.0, 1.0, 1.5), (0.0, 0.0, 0.0), heading_to=(2.0, 3.0, 1.5))
    refuge = choose_refuge(refuge_candidates(here, holding), holding, here)
    assert distance_to_track(refuge, holding) >= REFUGE_CLEAR_M
    assert np.linalg.norm(refuge - here) == pytest.approx(s if s >= REFUGE_CLEAR_M else 2 * s)
    # With only candidates on its way (the map forbids the others), the one farthest off it.
    on_the_way = [here + [0.0, s, 0.0], here + [0.0, 0.0, 0.3]]
    assert np.allclose(choose_refuge(on_the_way, holding, here), here + [0.0, 0.0, 0.3])
    # A peer hovering with nowhere to go: the first candidate (vertical), whatever the distances.
    hovering = Neighbour(1, (1.0, 2.0, 1.5), (0.0, 0.0, 0.0))
    assert np.allclose(choose_refuge(refuge_candidates(here, hovering), hovering, here), here + [0.0, 0.0, s])


def test_with_no_refuge_clear_of_the_way_a_drone_never_steps_towards_the_drone_it_gives_way_to() -> None:
    # gen:1 at 20x15 m, two drones leaving their take-off pocket head-on: drone 2 gave way to drone 1 by a step
    # 0.6 m towards it (the candidate farthest off drone 1's segment of the moment, on its next one), and they
    # touched 2 s later.
    here = np.array([11.29, 10.05, 1.07])
    coming = Neighbour(1, (10.12, 10.03, 1.12), (0.4, 0.0, 0.1), heading_to=(10.5, 9.9, 1.1))
    towards = np.array([10.72, 10.33, 1.05])
    assert distance_to_track(towards, coming) < REFUGE_CLEAR_M
    # its map let it fly straight to no other step (the take-off pocket): it stays where it is
    assert np.allclose(choose_refuge([towards], coming, here), here)


def test_a_refuge_is_in_the_way_once_the_peer_turns_onto_a_segment_through_it() -> None:
    # Two drones coming home, their take-off points 1.3 m apart (gen:1, coordinated): drone 2 stepped aside for
    # drone 1 to a refuge 0.28 m from drone 1's home while drone 1 flew its second-last segment; drone 1 then
    # turned for home, and both waited (8 s) until they timed out.
    refuge = np.array([10.26, 9.54, 1.3])
    second_last = Neighbour(1, (11.6, 9.0, 1.2), (-0.5, 0.5, -0.4), heading_to=(11.3, 9.3, 0.9))
    assert not refuge_in_the_way(refuge, second_last)
    home_leg = second_last._replace(position=(11.3, 9.3, 0.9), heading_to=(10.0, 9.43, 1.5))
    assert refuge_in_the_way(refuge, home_leg)
    assert not refuge_in_the_way(refuge + [0.0, REFUGE_CLEAR_M + 0.1, 0.0], home_leg)
    # a hovering peer going nowhere has no way to be in
    parked = Neighbour(1, (10.5, 9.5, 1.3), (0.0, 0.0, 0.0))
    assert not refuge_in_the_way(refuge, parked)


def test_distance_to_segment_is_the_distance_to_its_nearest_point() -> None:
    a, b = np.array([0.0, 0.0, 0.0]), np.array([2.0, 0.0, 0.0])
    assert distance_to_segment(np.array([1.0, 0.5, 0.0]), a, b) == pytest.approx(0.5)
    assert distance_to_segment(np.array([3.0, 0.0, 0.0]), a, b) == pytest.approx(1.0)
    assert distance_to_segment(np.array([0.0, 0.0, 1.0]), a, a) == pytest.approx(1.0)  # a point segment


def test_distance_to_track_is_measured_to_the_covered_segment() -> None:
    peer = Neighbour(1, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0))  # covers x 0..3 m in the 3 s horizon
    assert distance_to_track(np.array([1.5, 2.0, 0.0]), peer) == pytest.approx(2.0)
    assert distance_to_track(np.array([-1.0, 0.0, 0.0]), peer) == pytest.approx(1.0)  # behind it
    assert distance_to_track(np.array([5.0, 0.0, 0.0]), peer) == pytest.approx(2.0)  # beyond the horizon
    # with a segment to fly, that segment, whatever the velocity
    flying = Neighbour(1, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), heading_to=(0.0, 5.0, 0.0))
    assert distance_to_track(np.array([1.0, 4.0, 0.0]), flying) == pytest.approx(1.0)


def test_after_stepping_aside_a_drone_rejoins_its_segment_unless_the_way_on_is_clear() -> None:
    # box world: a wall stub at x = 4 from y = 3 to the north wall; the segment passes 0.7 m south of its end
    is_clear = clear_in(load_world("box"))
    left_at, target = (3.0, 2.3, 1.2), (5.0, 2.3, 1.2)
    assert is_clear(left_at, target)
    north, south = (3.3, 3.2, 1.2), (3.0, 1.6, 1.2)  # refuges beside the stub's end, and away from it
    assert is_clear(left_at, north) and not is_clear(north, target)  # straight on would clip the stub's end
    assert resume_from(north, left_at, target, is_clear) == left_at
    assert resume_from(south, left_at, target, is_clear) == south


def test_a_refuge_in_a_third_drones_way_is_not_taken() -> None:
    # drone 3 in a doorway gives way to drone 2 behind it; drone 1 flies west along the corridor in front of it
    here = np.array([21.1, 9.3, 1.5])
    behind = Neighbour(2, (21.1, 8.2, 1.3), (0.0, 0.8, 0.0), heading_to=(21.1, 11.0, 1.3))
    corridor = Neighbour(1, (23.0, 9.6, 1.5), (-1.2, 0.0, 0.0), heading_to=(15.0, 9.6, 1.5))
    candidates = refuge_candidates(here, behind)
    kept = off_the_others_ways(candidates, [corridor])
    assert kept and len(kept) < len(candidates)
    assert all(distance_to_track(c, corridor) >= REFUGE_CLEAR_M for c in kept)
    assert off_the_others_ways(candidates, []) == candidates


def test_a_refuge_is_not_reached_through_a_drone() -> None:
    # drone 2 hovers 0.8 m above drone 1's way; the step down would pass through drone 1
    here = np.array([26.3, 10.9, 2.1])
    below = Neighbour(1, (26.2, 10.9, 1.3), (0.0, 0.5, 0.0), heading_to=(26.2, 12.5, 1.3))
    candidates = refuge_candidates(here, below)
    kept = moves_clear_of(here, candidates, [below])
    assert all(c[2] > 1.3 for c in kept)  # nothing down through it
    assert any(c[2] < 1.3 for c in candidates)
    assert len(moves_clear_of(here, candidates, [])) == len(candidates)


def test_the_closest_approach_is_now_when_drones_move_apart_and_at_most_the_horizon_ahead() -> None:
    offset = np.array([4.0, 0.0, 0.0])
    assert closest_approach(offset, np.array([1.0, 0.0, 0.0]), 1.0) == pytest.approx(4.0)  # moving apart
    assert closest_approach(offset, np.array([-3.0, 0.0, 0.0]), 1.0) == pytest.approx(1.0)  # 1 s of closing
    assert closest_approach(offset, np.array([-8.0, 0.0, 0.0]), 1.0) == pytest.approx(0.0)  # head-on, within it
    assert closest_approach(np.array([4.0, 1.5, 0.0]), np.array([-8.0, 0.0, 0.0]), 1.0) == pytest.approx(1.5)
    assert closest_approach(offset, np.zeros(3), 1.0) == pytest.approx(4.0)  # neither moving
