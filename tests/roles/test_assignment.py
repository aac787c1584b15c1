import math

import numpy as np
import pytest

from swarm.roles.assignment import (
    Candidate,
    assign_targets,
    merge_candidates,
    overlapped,
    remove_overlapped,
    schedule_gain,
    utility,
)


def cand(x: float, y: float, gain: float = 10.0, owner: int = 1, z: float = 1.0) -> Candidate:
    """A candidate whose frontier point is 0.8 m east of its viewpoint."""
    return Candidate((x, y, z), (x + 0.8, y, z), gain, owner)


def ring(radius: float = 4.0, n: int = 72, z: float = 1.0) -> np.ndarray:
    angles = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return np.column_stack([radius * np.cos(angles), radius * np.sin(angles), np.full(n, z)])


# --- utility (Eq. 3.2 / 3.3), reference vectors of research notes 2.5 ---------------------------------------------


@pytest.mark.parametrize(
    ("d_i", "d_tot", "expected"),
    [(1, 8, 19.47), (1, 2, 16.76), (1, 0.5, 9.20), (2, 8, 15.94), (4, 8, 10.69), (4, 2, 9.20)],
)
def test_utility_matches_reference_vectors_for_three_uavs(d_i: float, d_tot: float, expected: float) -> None:
    assert abs(utility(25.0, d_i, [d_tot / 2, d_tot / 2], 0.2) - expected) < 0.005
    # only the sum of the others' distances matters
    split = utility(25.0, d_i, [d_tot / 4, 3 * d_tot / 4], 0.2)
    assert split == pytest.approx(utility(25.0, d_i, [d_tot / 2] * 2, 0.2))


@pytest.mark.parametrize(("d", "expected"), [(1, 20.47), (2, 16.76), (3, 13.72), (4, 11.23), (5, 9.20), (6, 7.53)])
def test_utility_matches_reference_vectors_for_a_single_uav(d: float, expected: float) -> None:
    assert abs(utility(25.0, d, [], 0.2) - expected) < 0.005


def test_utility_is_zero_on_a_target_the_others_sit_on() -> None:
    assert utility(25.0, 1.0, [0.0, 0.0], 0.2) == 0.0
    assert utility(25.0, 1.0, [0.0, 0.0], 0.0) == 0.0


# --- scheduling (Eq. 3.5) -----------------------------------------------------------------------------------------


def test_scheduling_multipliers_for_sigma_3_are_isotropic_in_3d() -> None:
    distances = np.array([0.5, 1.0, 2.0, 3.0, 6.0])
    centre = np.array([1.0, -2.0, 0.5])
    direction = np.array([1.0, 2.0, 2.0]) / 3.0  # unit, not along an axis
    points = centre + distances[:, None] * direction
    got = schedule_gain(np.full(5, 2.0), points, tuple(centre), 3.0) / 2.0
    # the notes' 3-decimal values; at 3 m they print 0.394 where 1 - e^-0.5 = 0.3935 rounds to 0.393
    assert np.allclose(got, [0.014, 0.054, 0.199, 0.394, 0.865], rtol=0.0, atol=1e-3)
    assert got[3] == pytest.approx(1.0 - math.exp(-0.5), abs=1e-12)
    assert schedule_gain(np.array([7.0]), centre[None, :], tuple(centre), 3.0)[0] == 0.0


def test_scheduling_refuses_non_positive_sigma() -> None:
    with pytest.raises(ValueError):
        schedule_gain(np.ones(1), np.zeros((1, 3)), (0.0, 0.0, 0.0), 0.0)


# --- assignment (Alg. 3.5) ----------------------------------------------------------------------------------------


def two_clusters() -> list[Candidate]:
    east = [cand(6.0, dy, gain=30.0, owner=1) for dy in (-0.4, 0.0, 0.4)]
    west = [cand(-6.0, dy, gain=28.0, owner=2) for dy in (-0.4, 0.0, 0.4)]
    return east + west


NEIGHBOURS = {1: (0.0, 0.0, 1.0), 2: (0.6, 0.0, 1.0)}


def test_neighbouring_drones_are_spread_over_far_apart_clusters_by_scheduling() -> None:
    # The best pair is drone 2 (0.6 m nearer) and the east cluster; scheduling then sends drone 1 west.
    got = assign_targets(two_clusters(), NEIGHBOURS, lam=0.2, sigma=3.0)
    assert got[2] is not None and got[2].viewpoint[0] == 6.0
    assert got[1] is not None and got[1].viewpoint[0] == -6.0


def test_the_best_pair_is_assigned_first_not_the_lowest_id() -> None:
    # Drone 1 sits between a small target beside drone 2 and a large one far off; drone 2 sits on the large one.
    # In id order drone 1 would take the large target (its best) and send drone 2 to the small one; the best
    # pair is drone 2 and the large target, and drone 1 takes the small one.
    small, large = cand(2.0, 0.0, gain=5.0), cand(10.0, 0.0, gain=50.0)
    got = assign_targets([small, large], {1: (0.0, 0.0, 1.0), 2: (9.0, 0.0, 1.0)}, lam=0.2, sigma=3.0)
    assert got == {1: small, 2: large}


def test_without_scheduling_both_drones_pick_the_same_cluster() -> None:
    got = assign_targets(two_clusters(), NEIGHBOURS, lam=0.2, sigma=1e-6)
    assert got[1] is not None and got[2] is not None
    assert got[1] != got[2]  # the assigned candidate is still taken out...
    assert got[1].viewpoint[0] == got[2].viewpoint[0] == 6.0  # ...but its neighbour in the cluster is next best


def test_a_leftover_near_one_drones_target_is_not_worth_a_second_drone_but_a_far_one_is() -> None:
    """The tail of the office mission: three drones sent one by one to floor frontiers 2-4 m apart in one corner
    20 m away. What the first drone will see there leaves the rest under the trip's worth for the others."""
    corner = [cand(20.0, 0.0, gain=5.0), cand(20.0, 3.0, gain=4.0)]
    drones = {1: (16.0, 0.0, 1.0), 2: (0.0, 0.0, 1.0), 3: (0.0, 2.0, 1.0)}
    every = assign_targets(corner, drones, lam=0.2, sigma=6.0)
    assert sum(c is not None for c in every.values()) == 2  # without a minimum: a second drone goes 20 m
    got = assign_targets(corner, drones, lam=0.2, sigma=6.0, min_gain=2.0)
    assert got == {1: corner[0], 2: None, 3: None}  # 4 m3 x (1 - exp(-9 / 72)) = 0.47 m3 left for the others
    far = cand(0.0, 10.0, gain=4.0)  # one at the other end is still another drone's
    got = assign_targets([*corner, far], drones, lam=0.2, sigma=6.0, min_gain=2.0)
    assert got[1] == corner[0] and got[3] == far and got[2] is None


def test_single_drone_gets_the_nearest_of_equal_gain_candidates() -> None:
    near = cand(0.0, 2.0)
    others = [cand(3.0, 0.0), cand(-5.0, 0.0), cand(0.0, -4.0, z=2.0)]
    for order in ([near, *others], [*others, near], [others[0], near, *others[1:]]):
        assert assign_targets(order, {4: (0.0, 0.0, 1.0)}, lam=0.2, sigma=3.0) == {4: near}


def test_distances_are_the_ones_given_the_way_round_a_floor_not_the_line_through_it() -> None:
    # Drone 2 is right above the target, a storey up; drone 1 is 6 m off on the same storey. Through the floor
    # drone 2 is nearer (the default, straight lines); the way down the stairwell is 20 m, and drone 1 goes.
    target = cand(6.0, 0.0, z=1.0)
    positions = {1: (0.0, 0.0, 1.0), 2: (6.0, 0.0, 4.0)}
    assert assign_targets([target], positions, lam=0.2, sigma=3.0) == {1: None, 2: target}

    def travel(starts: np.ndarray, goals: np.ndarray) -> np.ndarray:
        straight = np.linalg.norm(starts[:, None, :] - goals[None, :, :], axis=2)
        upstairs = starts[:, 2] > 2.5
        return np.where(upstairs[:, None], 20.0, straight)

    assert assign_targets([target], positions, lam=0.2, sigma=3.0, distances=travel) == {1: target, 2: None}


def test_a_drone_avoids_targets_next_to_another_member() -> None:
    beside_2, far_side = cand(3.9, 0.0), cand(-4.5, 0.0)
    alone = assign_targets([beside_2, far_side], {1: (0.0, 0.0, 1.0)}, lam=0.2, sigma=3.0)
    assert alone[1] == beside_2
    both = assign_targets([beside_2, far_side], {1: (0.0, 0.0, 1.0), 2: (4.0, 0.0, 1.0)}, lam=0.2, sigma=3.0)
    assert both == {1: far_side, 2: beside_2}


def test_current_bonus_keeps_a_drone_on_its_current_target_when_a_slightly_better_one_appears() -> None:
    current, better = cand(3.0, 0.0, gain=10.0), cand(-3.0, 0.0, gain=11.0)
    here = {1: (0.0, 0.0, 1.0)}
    assert assign_targets([current, better], here, lam=0.2, sigma=3.0)[1] == better
    kept = assign_targets(
        [current, better], here, lam=0.2, sigma=3.0, current={1: (3.2, 0.0, 1.0)}, current_bonus=1.5, keep_radius=0.5
    )
    assert kept[1] == current
    # the bonus applies only within keep_radius of the current target
    moved = assign_targets(
        [current, better], here, lam=0.2, sigma=3.0, current={1: (3.8, 0.0, 1.0)}, current_bonus=1.5, keep_radius=0.5
    )
    assert moved[1] == better


def test_own_bonus_prefers_the_members_own_frontiers() -> None:
    theirs, mine = cand(3.0, 0.0, gain=10.5, owner=2), cand(-3.0, 0.0, gain=10.0, owner=1)
    here = {1: (0.0, 0.0, 1.0)}
    assert assign_targets([theirs, mine], here, lam=0.2, sigma=3.0)[1] == theirs
    assert assign_targets([theirs, mine], here, lam=0.2, sigma=3.0, own_bonus=1.2)[1] == mine


def test_members_beyond_the_number_of_candidates_get_none() -> None:
    positions = {3: (0.0, 0.0, 1.0), 1: (1.0, 0.0, 1.0), 2: (2.0, 0.0, 1.0)}
    got = assign_targets([cand(5.0, 0.0), cand(-5.0, 0.0)], positions, lam=0.2, sigma=3.0)
    assert list(got) == [1, 2, 3]
    # drone 2 is nearest the east target, drone 3 the west one; drone 1, between them, is left without
    assert got[2] == cand(5.0, 0.0) and got[3] == cand(-5.0, 0.0)
    assert got[1] is None
    assert assign_targets([], positions, lam=0.2, sigma=3.0) == {1: None, 2: None, 3: None}


def test_exact_ties_break_the_same_way_whatever_the_input_order() -> None:
    west, east = cand(-2.0, 0.0), cand(2.0, 0.0)
    here = {1: (0.0, 0.0, 1.0)}
    assert assign_targets([east, west], here, lam=0.2, sigma=3.0) == {1: west}
    assert assign_targets([west, east], here, lam=0.2, sigma=3.0) == {1: west}


def test_candidate_refuses_a_negative_or_nan_gain() -> None:
    for bad in (-0.1, math.nan, math.inf):
        with pytest.raises(ValueError):
            Candidate((0.0, 0.0, 1.0), (1.0, 0.0, 1.0), bad, 1)


# --- frontier processing with shared maps -------------------------------------------------------------------------


def test_merge_drops_known_exhausted_and_duplicate_candidates() -> None:
    known = cand(11.0, 0.0, gain=5.0, owner=1)  # its point lies where the leader's map is known
    exhausted = cand(0.0, 5.0, gain=5.0, owner=2)  # 0.3 m from a viewpoint already visited
    weaker_dup, stronger_dup = cand(3.0, 3.0, gain=4.0, owner=2), cand(3.2, 3.0, gain=6.0, owner=3)
    beyond_exhausted = cand(0.0, 6.0, gain=3.0, owner=3)  # 1.04 m from it
    plain = cand(-3.0, 0.0, gain=2.0, owner=1)

    def gain_now(points: np.ndarray) -> np.ndarray:
        return np.where(points[:, 0] > 10.0, 0.0, 5.0)

    kwargs = dict(min_gain=0.15, exhausted=[(0.3, 5.0, 1.0)], exhausted_radius=0.8, merge_radius=0.5)
    got = merge_candidates(
        [known, plain], {2: [exhausted, weaker_dup], 3: [stronger_dup, beyond_exhausted]}, gain_now=gain_now, **kwargs
    )
    assert got == [stronger_dup, beyond_exhausted, plain]
    shuffled = merge_candidates(
        [plain, known], {3: [beyond_exhausted, stronger_dup], 2: [weaker_dup, exhausted]}, gain_now=gain_now, **kwargs
    )
    assert shuffled == got
    without_map = merge_candidates([known, plain], {2: [exhausted, weaker_dup]}, gain_now=None, **kwargs)
    assert without_map == [known, weaker_dup, plain]  # no map to ask: the known one stays


def test_merge_keeps_the_far_end_of_a_chain_of_near_duplicates() -> None:
    a, b, c = cand(0.0, 0.0, gain=9.0), cand(0.4, 0.0, gain=8.0), cand(0.8, 0.0, gain=7.0)
    got = merge_candidates(
        [a, b, c], {}, gain_now=None, min_gain=0.0, exhausted=[], exhausted_radius=1.0, merge_radius=0.5
    )
    assert got == [a, c]  # b is a's duplicate; c is only b's, and b was dropped


# --- frontier processing without maps (Alg. 3.2 / 3.4) ------------------------------------------------------------


def test_overlapped_marks_points_inside_or_on_a_ring_outline_and_not_outside_it() -> None:
    inside = [(0.0, 0.0, 1.0), (2.0, 1.5, 1.0), (-3.0, -1.0, 1.0)]
    on_outline = [(4.0, 0.0, 1.0)]
    outside = [(6.0, 0.0, 1.0), (0.0, 6.0, 1.0), (0.0, 0.0, 3.0)]  # east, north, and above the ring's layer
    mask = overlapped(np.array(inside + on_outline + outside), ring())
    assert mask.tolist() == [True] * 4 + [False] * 3
    assert overlapped(np.array(inside), np.zeros((0, 3))).tolist() == [False] * 3
    assert overlapped(np.zeros((0, 3)), ring()).shape == (0,)


def literal_alg_3_4(a: np.ndarray, b: np.ndarray, eps: float) -> list[bool]:
    """The thesis's loops, with the notes' fixes and the y row widened to a (y, z) band."""
    out = []
    for p in a:
        inf = sup = eq = 0
        for q in b:
            if abs(p[1] - q[1]) < eps and abs(p[2] - q[2]) < eps:
                if p[0] < q[0] - eps:
                    inf += 1
                elif p[0] > q[0] + eps:
                    sup += 1
                else:
                    eq += 1
        out.append((inf > 0 and sup > 0) or eq > 0)
    return out


def test_overlapped_matches_the_literal_algorithm_across_blocks() -> None:
    rng = np.random.default_rng(7)
    a, b = rng.uniform(0.0, 6.0, (700, 3)), rng.uniform(0.0, 6.0, (120, 3))  # 700 > one block of 512
    got = overlapped(a, b, 0.5)
    assert got.tolist() == literal_alg_3_4(a, b, 0.5)
    assert 0 < got.sum() < len(a)  # the comparison saw both outcomes


def test_remove_overlapped_drops_a_drones_frontiers_inside_anothers_outline() -> None:
    outline = [Candidate(tuple(p), tuple(p), 1.0, 2) for p in ring()]
    inside_1, outside_1 = cand(-0.8, 0.0, gain=2.0, owner=1), cand(-0.8, 7.0, gain=2.0, owner=1)
    inside_3 = cand(-1.8, 1.0, gain=3.0, owner=3)
    got = remove_overlapped({1: [inside_1, outside_1], 2: outline, 3: [inside_3]})
    assert set(got) == {outside_1, *outline}
    assert got[0] == outside_1 and len(got) == 1 + len(outline)
    assert remove_overlapped({1: [inside_1, outside_1]}) == [inside_1, outside_1]


def test_a_drone_does_not_take_another_drones_current_target() -> None:
    # The candidate next to drone 1 is drone 2's current target: without the penalty it is drone 1's best pair,
    # drone 1 grabs it and drone 2 must turn round; with it, each keeps heading where it was going.
    near_1 = Candidate((2.0, 0.0, 1.0), (2.5, 0.0, 1.0), 10.0, 1)
    far = Candidate((6.0, 4.0, 1.0), (6.5, 4.0, 1.0), 10.0, 1)
    positions = {1: (0.0, 0.0, 1.0), 2: (4.0, 0.0, 1.0)}
    plain = assign_targets([near_1, far], positions, lam=0.2, sigma=3.0)
    assert plain[1] == near_1
    kept = assign_targets(
        [near_1, far], positions, lam=0.2, sigma=3.0, current={2: near_1.viewpoint}, current_bonus=3.0
    )
    assert kept[2] == near_1 and kept[1] == far


def test_a_member_is_not_given_a_viewpoint_it_could_not_reach_and_another_member_is() -> None:
    near_1, far = cand(2.0, 0.0, gain=20.0), cand(-6.0, 0.0, gain=10.0)
    positions = {1: (0.0, 0.0, 1.0), 2: (8.0, 0.0, 1.0)}
    assert assign_targets([near_1, far], positions, lam=0.2, sigma=1e-6) == {1: near_1, 2: far}
    got = assign_targets(
        [near_1, far], positions, lam=0.2, sigma=1e-6, unreachable={1: [(2.3, 0.0, 1.0)]}, unreachable_radius=0.5
    )
    assert got == {1: far, 2: near_1}
    stuck = assign_targets(
        [near_1], {1: positions[1]}, lam=0.2, sigma=3.0, unreachable={1: [(2.0, 0.4, 1.0)]}, unreachable_radius=0.5
    )
    assert stuck == {1: None}  # nothing it can reach: no target rather than the one it cannot


def _leftover_round(current: dict[int, tuple[float, float, float]] | None, **kwargs: object) -> dict[int, object]:
    """Drone 1 idle at the origin; drone 2 at (8, 0) on its way to its target at (10, 0); a leftover 2.8 m on
    from there."""
    heading_2 = cand(10.0, 0.0, gain=5.0, owner=2)
    leftover = cand(12.0, 2.0, gain=7.0)
    positions = {1: (0.0, 0.0, 1.0), 2: (8.0, 0.0, 1.0)}
    got = assign_targets(
        [heading_2, leftover], positions, lam=0.2, sigma=1e-6, current=current, current_bonus=3.0, **kwargs
    )
    return {k: (None if c is None else ("heading_2" if c == heading_2 else "leftover")) for k, c in got.items()}


def test_a_leftover_on_a_busy_members_way_is_left_to_it_and_not_sent_far() -> None:
    # Drone 2 reaches the leftover 2 + 2.8 m from now; drone 1 would fly 12.2 m to it. Without knowing where
    # drone 2 is heading, the leader sends drone 1 (the tail of a generated building: 30 m for a 7 m^3 leftover).
    assert _leftover_round(None) == {1: "leftover", 2: "heading_2"}
    assert _leftover_round({2: (10.0, 0.0, 1.0)}) == {1: None, 2: "heading_2"}


def test_a_member_closer_than_the_busy_ones_way_round_still_takes_the_leftover() -> None:
    # Drone 2 heads away from the leftover (to (2, 0), 6 m back): 6 + 10.2 m by way of its target, drone 1's 12.2 m
    # direct is sooner.
    heading_away = cand(2.0, 0.0, gain=5.0, owner=2)
    leftover = cand(12.0, 2.0, gain=7.0)
    got = assign_targets(
        [heading_away, leftover],
        {1: (0.0, 0.0, 1.0), 2: (8.0, 0.0, 1.0)},
        lam=0.2,
        sigma=1e-6,
        current={2: heading_away.viewpoint},
        current_bonus=3.0,
    )
    assert got == {1: leftover, 2: heading_away}


def test_a_members_own_target_is_not_taken_from_it_by_one_passing_nearer() -> None:
    # Drone 1 is already on its way to the leftover: drone 2 passing nearer does not make it turn round (the
    # current-target bonus alone decides whether another member takes it).
    assert _leftover_round({1: (12.0, 2.0, 1.0), 2: (10.0, 0.0, 1.0)}) == {1: "leftover", 2: "heading_2"}


def test_a_leftover_is_not_left_to_a_busy_member_that_cannot_reach_it() -> None:
    got = _leftover_round({2: (10.0, 0.0, 1.0)}, unreachable={2: [(12.0, 2.0, 1.0)]}, unreachable_radius=0.5)
    assert got == {1: "leftover", 2: "heading_2"}


def test_the_way_round_counts_when_a_leftover_is_left_to_a_busy_member() -> None:
    # Through the map, drone 2's way on from its target to the leftover is 20 m (a wall between): drone 1 goes.
    def through_wall(starts: np.ndarray, goals: np.ndarray) -> np.ndarray:
        straight = np.linalg.norm(starts[:, None, :] - goals[None, :, :], axis=2)
        walled = (np.abs(starts[:, None, 0] - 10.0) < 0.1) & (np.abs(goals[None, :, 0] - 12.0) < 0.1)
        return np.where(walled, 20.0, straight)

    assert _leftover_round({2: (10.0, 0.0, 1.0)}, distances=through_wall) == {1: "leftover", 2: "heading_2"}


def test_a_busy_member_is_left_only_the_one_candidate_it_reaches_next() -> None:
    # Three candidates beyond drone 2's target, each sooner by way of it than from idle drone 1: drone 2 can take
    # one next, not all three; drone 1 takes another (on a generated building, leaving every one to the busy
    # drones kept the third drone at home while 18 candidates waited).
    heading_2 = cand(10.0, 0.0, gain=5.0, owner=2)
    beyond = [cand(12.0, 1.0, gain=7.0), cand(12.0, -3.0, gain=7.0), cand(14.0, 0.0, gain=7.0)]
    got = assign_targets(
        [heading_2, *beyond],
        {1: (0.0, 0.0, 1.0), 2: (8.0, 0.0, 1.0)},
        lam=0.2,
        sigma=1e-6,
        current={2: heading_2.viewpoint},
        current_bonus=3.0,
    )
    assert got[2] == heading_2
    assert got[1] in beyond[1:]  # not the first: drone 2's next, the nearest to its target
