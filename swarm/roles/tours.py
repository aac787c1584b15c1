"""Tours: the leader divides the candidates between members by position, and each member takes the first
candidate of its own tour (`explore.assignment = "tours"`; issue 21, after FUEL and RACER).

Utility assignment (`swarm.roles.assignment`) sends each member to its best (gain, distance) trade-off. Gains
differ fifty-fold, so a drone leaves small candidates beside it for a large one farther on, and those leftovers
make the mission's tail: every drone is later sent back across the building for them. Here gain only decides
what is worth a trip (`min_gain`); where to go first is a question of routes:

1. **Partition.** Each candidate belongs to the member that flies there soonest (`distances`, through the
   leader's map) or, for a member that will fly home when the cluster is done (`homes`), that adds least to
   its way home: its way there and on home, less its way home from where it is (a leftover on one drone's way
   home is that drone's, though another is nearer to it now). The member already heading for a candidate
   counts this as `current_bonus` times less, so two members about as far from it do not swap it between
   rounds.
2. **Tours.** Each member orders its candidates as a tour from where it is: nearest neighbour, then 2-opt
   (`between`, the distances among the viewpoints). The tour ends at the member's home when it has one (where
   it flies once the cluster is done: the leftovers on its way home come last), else at its last stop. Its
   target is the tour's first candidate; a candidate it is already heading for stays first unless a tour that
   starts elsewhere is shorter, the way to the current target counted `current_bonus` times shorter again.
3. **Balance.** A member with nothing takes, from a tour of two or more, the candidate it reaches soonest
   ahead of the tour's owner (the owner's arrival is its way along its tour); none is taken when the owner
   comes first to all of them. It does not chase what another drone will pick up on its way.

Pure: positions, candidates and distance functions in, one candidate (or None) per member out. Tours are made
again every round from the current map, so nothing is remembered between rounds but the current targets.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from swarm.config import Vec3
from swarm.roles.assignment import Candidate, as_vectors, blocked_for, order_key, pairwise_distances, within_radius

TWO_OPT_PASSES = 8  # 2-opt passes over a tour at most: n numpy steps of O(n) each; most tours settle in 2-3


def assign_tours(
    candidates: Sequence[Candidate],
    positions: Mapping[int, Vec3],
    *,
    current: Mapping[int, Vec3] | None = None,
    current_bonus: float = 1.0,
    keep_radius: float = 1.0,
    unreachable: Mapping[int, Sequence[Vec3] | np.ndarray] | None = None,
    unreachable_radius: float = 1.0,
    min_gain: float = 0.0,
    distances: Callable[[np.ndarray, np.ndarray], np.ndarray] = pairwise_distances,
    between: Callable[[np.ndarray], np.ndarray] | None = None,
    homes: Mapping[int, Vec3] | None = None,
) -> dict[int, Candidate | None]:
    """One candidate (or None) per member of `positions`: the first of its tour (module docstring).
    `distances` (starts (M, 3), goals (N, 3)) -> (M, N) metres, as in `assign_targets`; `between` (views (N, 3))
    -> (N, N) metres among the viewpoints, Euclidean by default. A member with a home in `homes` (where it flies
    when the cluster is done) has a tour that ends there. A member is never given a candidate within
    `unreachable_radius` of a viewpoint it could not plan a path to; candidates under `min_gain` are nobody's."""
    members = sorted(positions)
    result: dict[int, Candidate | None] = {m: None for m in members}
    pool = sorted((c for c in candidates if c.gain >= min_gain), key=order_key)
    if not pool or not members:
        return result
    views = as_vectors([c.viewpoint for c in pool])
    reach = np.asarray(distances(as_vectors([positions[m] for m in members]), views), dtype=float).reshape(
        len(members), -1
    )
    reach[blocked_for(members, views, unreachable, unreachable_radius)] = np.inf
    heading = [None if current is None else current.get(m) for m in members]
    to_home = _ways_home(members, homes or {}, views, distances)
    claim = reach + np.maximum(_detours(members, positions, homes or {}, to_home, len(pool), distances), 0.0)
    for row, target in enumerate(heading):
        if target is not None:
            mine = within_radius(views, target, keep_radius)
            claim[row, mine] /= current_bonus
    reachable = np.isfinite(claim).any(axis=0)
    if not reachable.any():
        return result
    owner = np.where(reachable, np.argmin(np.where(np.isfinite(claim), claim, np.inf), axis=0), -1)
    among = np.asarray(between(views) if between is not None else pairwise_distances(views, views), dtype=float)
    among = np.minimum(among, among.T)  # the way there and back is one way: take the shorter estimate
    tours = {
        row: _tour(
            reach[row],
            among,
            np.flatnonzero(owner == row),
            _current_index(views, heading[row], keep_radius),
            current_bonus,
            to_home.get(row),
        )
        for row in range(len(members))
    }
    _balance(tours, reach, among)
    for row, member in enumerate(members):
        if tours[row]:
            result[member] = pool[tours[row][0]]
    return result


def _ways_home(
    members: list[int],
    homes: Mapping[int, Vec3],
    views: np.ndarray,
    distances: Callable[[np.ndarray, np.ndarray], np.ndarray],
) -> dict[int, np.ndarray]:
    """Member row -> (N,) the way from each viewpoint to its home (measured from the home: one search per home)."""
    rows = [row for row, m in enumerate(members) if m in homes]
    if not rows:
        return {}
    ways = np.asarray(distances(as_vectors([homes[members[row]] for row in rows]), views), dtype=float)
    return {row: ways.reshape(len(rows), -1)[i] for i, row in enumerate(rows)}


def _detours(
    members: list[int],
    positions: Mapping[int, Vec3],
    homes: Mapping[int, Vec3],
    to_home: dict[int, np.ndarray],
    candidates: int,
    distances: Callable[[np.ndarray, np.ndarray], np.ndarray],
) -> np.ndarray:
    """(M, N) what each candidate adds to a member's way home beyond its way there: the way on from it home less
    the member's way home from where it is now (0 for a member without a home)."""
    out = np.zeros((len(members), candidates))
    for row, way_on in to_home.items():
        direct = distances(as_vectors([positions[members[row]]]), as_vectors([homes[members[row]]]))
        out[row] = way_on - float(np.asarray(direct, dtype=float).reshape(-1)[0])
    return out


def _current_index(views: np.ndarray, target: Vec3 | None, keep_radius: float) -> int | None:
    if target is None:
        return None
    near = np.flatnonzero(within_radius(views, target, keep_radius))
    return None if len(near) == 0 else int(near[np.argmin(np.linalg.norm(views[near] - np.asarray(target), axis=1))])


def _tour(
    from_start: np.ndarray,
    among: np.ndarray,
    stops: np.ndarray,
    current: int | None,
    current_bonus: float,
    to_end: np.ndarray | None = None,
) -> list[int]:
    """The candidates `stops` as a tour from the member (`from_start`: its way to each) and, with `to_end` (the
    way from each to its home), back home: nearest neighbour then 2-opt. With its `current` target among them,
    the tour that starts there is kept unless the tour that starts elsewhere is shorter, the way to the current
    target counted `current_bonus` times shorter."""
    if len(stops) == 0:
        return []
    free = _two_opt(_nearest_neighbour(from_start, among, stops), from_start, among, to_end)
    if current is None or current not in stops or free[0] == current:
        return free
    rest = np.array([s for s in stops if s != current], dtype=int)
    kept = _two_opt([current, *_nearest_neighbour(among[current], among, rest)], None, among, to_end)
    kept_length = from_start[current] / current_bonus + _length(kept, among, to_end)
    free_length = from_start[free[0]] + _length(free, among, to_end)
    return kept if kept_length <= free_length else free


def _nearest_neighbour(from_start: np.ndarray, among: np.ndarray, stops: np.ndarray) -> list[int]:
    order: list[int] = []
    left = list(map(int, stops))
    way = from_start
    while left:
        nearest = min(left, key=lambda s: (way[s], s))
        order.append(nearest)
        left.remove(nearest)
        way = among[nearest]
    return order


def _length(order: Sequence[int], among: np.ndarray, to_end: np.ndarray | None = None) -> float:
    home = float(to_end[order[-1]]) if to_end is not None and order else 0.0
    return float(sum(among[a, b] for a, b in zip(order, order[1:]))) + home


def _two_opt(
    order: list[int], from_start: np.ndarray | None, among: np.ndarray, to_end: np.ndarray | None = None
) -> list[int]:
    """Reverse segments of the tour while that shortens it. With `from_start` (the member's way to each stop)
    the first stop may change; without, `order[0]` stays first. With `to_end` the tour ends at home (the way
    from each stop there); without, it ends at its last stop."""
    route = list(order)
    first = 0 if from_start is not None else 1
    for _ in range(TWO_OPT_PASSES):
        improved = False
        for i in range(first, len(route) - 1):
            before = from_start[route[i]] if i == 0 and from_start is not None else among[route[i - 1], route[i]]
            nodes = np.array(route)
            k = np.arange(i + 1, len(route))
            head = from_start[nodes[k]] if i == 0 and from_start is not None else among[route[i - 1], nodes[k]]
            last = k + 1 == len(route)
            following = nodes[np.minimum(k + 1, len(route) - 1)]
            end_old = 0.0 if to_end is None else to_end[nodes[k]]
            end_new = 0.0 if to_end is None else np.full(len(k), to_end[route[i]])
            after_old = np.where(last, end_old, among[nodes[k], following])
            after_new = np.where(last, end_new, among[route[i], following])
            gain = before + after_old - head - after_new
            best = int(np.argmax(gain))
            if gain[best] > 1e-9:
                j = int(k[best])
                route[i : j + 1] = reversed(route[i : j + 1])
                improved = True
        if not improved:
            break
    return route


def _balance(tours: dict[int, list[int]], reach: np.ndarray, among: np.ndarray) -> None:
    """Members with an empty tour take candidates they reach before the tours' owners do (module docstring)."""
    while True:
        idle = [row for row, tour in tours.items() if not tour and np.isfinite(reach[row]).any()]
        best: tuple[float, int, int, int] | None = None  # (lead, idle row, owner row, candidate)
        for owner_row, tour in tours.items():
            if len(tour) < 2:
                continue
            arrival = reach[owner_row, tour[0]] + np.concatenate([[0.0], np.cumsum(among[tour[:-1], tour[1:]])])
            for row in idle:
                lead = arrival - reach[row, tour]
                at = int(np.argmax(lead))
                if lead[at] > 0.0 and (best is None or lead[at] > best[0]):
                    best = (float(lead[at]), row, owner_row, tour[at])
        if best is None:
            return
        _, row, owner_row, stop = best
        tours[owner_row].remove(stop)
        tours[row] = [stop]
