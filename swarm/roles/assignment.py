"""The cluster leader's frontier processing and goal assignment (A. Mahdoui, "Communicating multi-UAV
system for cooperative SLAM-based exploration", PhD thesis, UTC Compiègne, 2018).

Pure functions over `Candidate`s, so the agent, the harness and the tests share one implementation and the
leader's decision can be replayed from what it received. Each loop the leader turns every member's reported
candidates into one set G, with `merge_candidates` when maps are shared or `remove_overlapped` when only frontiers
travel, then `assign_targets` hands G out greedily, the best (member, target) pair first, and lowers the gains near
every target it hands out so the next member goes elsewhere. An empty G after processing is the thesis's stop
condition (2.7);
what to do then is the caller's business.

Deviations from the thesis, all from working in 3D with viewpoints: distances are to the viewpoint a drone
flies to, the way it flies there through the caller's map (Euclidean in 3D without one); scheduling is isotropic
in 3D and applies to every remaining candidate (r_min = 0, r_max = inf); the scan-line overlap test uses a (y, z)
band instead of a y row.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from swarm.config import Vec3, vec3

_BLOCK = 512  # rows of a's points per overlap block: bounds the temporaries at _BLOCK x N_b x 3 floats


@dataclass(frozen=True)
class Candidate:
    """A place worth flying to: a safe viewpoint, the frontier point it looks at, and what looking there gains."""

    viewpoint: Vec3
    point: Vec3
    gain: float  # m^3 of unknown volume
    owner: int  # the drone that reported it

    def __post_init__(self) -> None:
        # Utility is the gain times a positive factor: a negative or NaN gain would turn the argmax upside down.
        if not (math.isfinite(self.gain) and self.gain >= 0.0):
            raise ValueError(f"candidate gain must be finite and >= 0, got {self.gain}")


def order_key(c: Candidate) -> tuple[float, int, tuple[float, ...], tuple[float, ...]]:
    """Highest gain first; the rest only makes equal gains come out in the same order on every leader."""
    return (-c.gain, c.owner, tuple(c.viewpoint), tuple(c.point))


def as_vectors(vectors: Sequence[Vec3] | np.ndarray) -> npt.NDArray[np.float64]:
    """(N, 3) floats, also for an empty input, so the vectorised code needs no special cases."""
    return np.asarray(vectors, dtype=float).reshape(-1, 3)


def pairwise_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N_a, N_b) Euclidean distances."""
    distances: np.ndarray = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    return distances


def _utilities(gain: np.ndarray, d_self: np.ndarray, d_tot: np.ndarray, n_others: int, lam: float) -> np.ndarray:
    """Eq. 3.2 (Eq. 3.3 without others) for many targets at once; `utility` and `assign_targets` share it.

    (n_c - 1) / d_tot is one over the others' mean distance: a target another member is sitting on (d_tot -> 0)
    is worth nothing to this one, and exactly 0 there rather than a division by zero."""
    if n_others == 0:
        return gain * np.exp(-lam * d_self)
    reachable = d_tot > 0.0
    crowd = n_others / np.where(reachable, d_tot, 1.0)
    return np.where(reachable, gain * np.exp(-lam * (d_self + crowd)), 0.0)


def utility(gain: float, d_self: float, d_others: Sequence[float], lam: float) -> float:
    """Mahdoui Eq. 3.2: U = I exp(-lam (d_i + (n_c - 1) / d_tot)), d_tot the sum of the other members' distances
    to the target; with no others (n_c = 1) Eq. 3.3: U = I exp(-lam d_i). d_tot == 0 -> U = 0."""
    u = _utilities(
        np.array([gain], float), np.array([d_self], float), np.array([math.fsum(d_others)]), len(d_others), lam
    )
    return float(u[0])


def schedule_gain(gain: np.ndarray, points: np.ndarray, assigned: Vec3, sigma: float) -> np.ndarray:
    """Eq. 3.5, isotropic in 3D: gain * (1 - exp(-|p - assigned|^2 / (2 sigma^2))).

    A candidate next to one already handed out mostly sees the same unknown volume, so its gain drops to near
    zero there and recovers with distance; that is what spreads the members out."""
    if not sigma > 0.0:
        raise ValueError(f"sigma must be > 0, got {sigma}")
    sq = np.sum((as_vectors(points) - np.asarray(assigned, dtype=float)) ** 2, axis=1)
    scheduled: np.ndarray = np.asarray(gain, dtype=float) * -np.expm1(-sq / (2.0 * sigma * sigma))
    return scheduled


def _near_any(points: np.ndarray, centres: np.ndarray, radius: float) -> np.ndarray:
    """Mask of points within radius (inclusive) of at least one centre."""
    if len(centres) == 0 or len(points) == 0:
        return np.zeros(len(points), dtype=bool)
    # a k-d tree: a leader merging three drones' 512 candidates each must not stall its event loop
    distance, _ = cKDTree(centres).query(points, distance_upper_bound=radius * (1 + 1e-12) + 1e-12)
    return np.isfinite(distance)


def _suppress_duplicates(ordered: Sequence[Candidate], radius: float) -> list[Candidate]:
    """Greedy non-maximum suppression on viewpoints: in gain order, keep a candidate unless a kept one is within
    radius. Only kept candidates suppress, so a chain of near neighbours does not wipe out its far end."""
    if not ordered:
        return []
    views = as_vectors([c.viewpoint for c in ordered])
    neighbours = cKDTree(views).query_ball_point(views, radius * (1 + 1e-12) + 1e-12)
    kept = np.zeros(len(ordered), dtype=bool)
    for i, close in enumerate(neighbours):
        kept[i] = not kept[close].any()
    return [c for c, k in zip(ordered, kept) if k]


def merge_candidates(
    own: Sequence[Candidate],
    received: Mapping[int, Sequence[Candidate]],
    *,
    gain_now: Callable[[np.ndarray], np.ndarray] | None,
    min_gain: float,
    exhausted: Sequence[Vec3],
    exhausted_radius: float,
    merge_radius: float,
) -> list[Candidate]:
    """The leader's frontier processing with shared maps: the union of every member's candidates, minus
    (1) candidates whose frontier point the leader's own fused map already knows (gain_now(points) < min_gain:
        a member reported it before patches from another drone that mapped it arrived; skipped when None),
    (2) candidates whose viewpoint is within exhausted_radius of an exhausted viewpoint (a drone already went
        there and looked; what is still unknown is not visible from there),
    (3) near-duplicates: of candidates whose viewpoints are within merge_radius, the highest gain is kept, since
        two members at the same frontier report it twice.
    Sorted by gain desc, then owner, then coordinates, so every leader produces the same list."""
    pool = sorted([*own, *(c for k in sorted(received) for c in received[k])], key=order_key)
    if not pool:
        return []
    keep = np.ones(len(pool), dtype=bool)
    if gain_now is not None:
        now = np.asarray(gain_now(as_vectors([c.point for c in pool])), dtype=float).reshape(len(pool))
        keep &= now >= min_gain  # NaN compares False: a gain the map cannot compute is not a target
    keep &= ~_near_any(as_vectors([c.viewpoint for c in pool]), as_vectors(exhausted), exhausted_radius)
    return _suppress_duplicates([c for c, k in zip(pool, keep) if k], merge_radius)


def _overlapped_block(a: np.ndarray, b: np.ndarray, eps: float) -> np.ndarray:
    """Alg. 3.4's second pass for a block of a's points (its first pass is implied by the second)."""
    d = b[None, :, :] - a[:, None, :]  # q - p, (n_a, n_b, 3)
    band = (np.abs(d[..., 1]) < eps) & (np.abs(d[..., 2]) < eps)
    dx = d[..., 0]
    on = (band & (np.abs(dx) <= eps)).any(axis=1)
    left = (band & (dx < -eps)).any(axis=1)
    right = (band & (dx > eps)).any(axis=1)
    overlapped: np.ndarray = on | (left & right)
    return overlapped


def overlapped(points_a: np.ndarray, points_b: np.ndarray, eps: float = 0.5) -> np.ndarray:
    """Frontier-only strategy (no shared maps): bool mask of a's points that lie inside or on the boundary of b's known
    region, which b's frontier points outline. Mahdoui's concave scan-line test (Alg. 3.4, with the fixes its
    pseudo-code needs) in 3D: among b's points within eps of p in y and z (strictly, as the thesis's row band), p is
    overlapped when one is within eps in x too (on the outline), or when some lie more than eps to p's left in x and
    some more than eps to its right (inside it). Assumes no obstacles inside b's region. Note the first branch also
    removes a frontier point that a and b share."""
    a, b = as_vectors(points_a), as_vectors(points_b)
    out = np.zeros(len(a), dtype=bool)
    if len(b) == 0:
        return out
    for start in range(0, len(a), _BLOCK):
        out[start : start + _BLOCK] = _overlapped_block(a[start : start + _BLOCK], b, eps)
    return out


def remove_overlapped(sets: Mapping[int, Sequence[Candidate]], eps: float = 0.5) -> list[Candidate]:
    """Alg. 3.2 for n_c >= 2 without maps: the union of all sets minus, for each ordered pair (a, b), a != b,
    a's candidates whose frontier points b's frontier points overlap (the union over pairs is our reading
    of the thesis's intersection for more than two drones). Sorted as `merge_candidates`."""
    points = {k: as_vectors([c.point for c in cands]) for k, cands in sets.items()}
    kept: list[Candidate] = []
    for a in sorted(sets):
        hit = np.zeros(len(points[a]), dtype=bool)
        for b in sorted(sets):
            if b != a:
                hit |= overlapped(points[a], points[b], eps)
        kept.extend(c for c, h in zip(sets[a], hit) if not h)
    return sorted(kept, key=order_key)


def _bonus(
    member: int,
    views: np.ndarray,
    owners: np.ndarray,
    current: Vec3 | None,
    current_bonus: float,
    own_bonus: float,
    keep_radius: float,
) -> np.ndarray:
    """Utility factors: staying on the current target avoids a U-turn every loop when a marginally better
    candidate appears; preferring own frontiers keeps a drone's direction (thesis 3.7)."""
    factor = np.where(owners == member, own_bonus, 1.0)
    if current is not None:
        factor = factor * np.where(within_radius(views, current, keep_radius), current_bonus, 1.0)
    return factor


def within_radius(views: np.ndarray, point: Vec3, radius: float) -> np.ndarray:
    within: np.ndarray = np.linalg.norm(views - np.asarray(point, dtype=float), axis=1) <= radius
    return within


def blocked_for(
    members: Sequence[int],
    views: np.ndarray,
    unreachable: Mapping[int, Sequence[Vec3] | np.ndarray] | None,
    radius: float,
) -> np.ndarray:
    """(members, views) True where a viewpoint lies within `radius` of one the member could not plan a path to:
    never that member's target (`assign_targets`, `swarm.roles.tours.assign_tours`)."""
    return np.array(
        [_near_any(views, as_vectors((unreachable or {}).get(m, [])), radius) for m in members], dtype=bool
    ).reshape(len(members), len(views))


def _left_to_passing(
    rows: list[int],
    heading: np.ndarray,
    via: np.ndarray,
    dist: np.ndarray,
    allowed: np.ndarray,
    views: np.ndarray,
    keep_radius: float,
) -> np.ndarray:
    """(members, cands) True where a candidate is left to a busy member: member `rows[b]`, flying to `heading[b]`,
    reaches its next candidate (the one it reaches soonest by way of its target, `via[b]`: its way to go plus the
    way on from there) sooner than another member flies to it directly; it takes it next. One candidate per busy
    member: it can pick up one on its way, not every one beyond its target (leaving them all to it kept a third
    drone at home while 18 candidates waited). A member's own current target is never taken from it here (the
    current-target bonus decides that), nor is a candidate left to a member that cannot reach it. Equal speeds
    are assumed: a way in metres is a time."""
    out = np.zeros(dist.shape, dtype=bool)
    own = [within_radius(views, vec3(target), keep_radius) for target in heading]  # each busy member's current target
    for b, row in enumerate(rows):
        eligible = allowed[row] & ~own[b]
        if not eligible.any():
            continue
        after = int(np.argmin(np.where(eligible, via[b], np.inf)))
        sooner = via[b, after] < dist[:, after]
        sooner[row] = False
        out[:, after] |= sooner
    for b, row in enumerate(rows):
        out[row] &= ~own[b]
    return out


def assign_targets(
    candidates: Sequence[Candidate],
    positions: Mapping[int, Vec3],
    *,
    lam: float,
    sigma: float,
    current: Mapping[int, Vec3] | None = None,
    current_bonus: float = 1.0,
    own_bonus: float = 1.0,
    keep_radius: float = 1.0,
    unreachable: Mapping[int, Sequence[Vec3] | np.ndarray] | None = None,
    unreachable_radius: float = 1.0,
    min_gain: float = 0.0,
    distances: Callable[[np.ndarray, np.ndarray], np.ndarray] = pairwise_distances,
) -> dict[int, Candidate | None]:
    """Alg. 3.5 with the best pair first: while a member is without a target, the (member, candidate) pair of
    highest utility over every member still waiting and every unassigned candidate is assigned (the leader
    assigns itself too); then the candidate is taken out and the gains of the rest are scheduled around its
    frontier point (Eq. 3.5: the information there overlaps). The thesis goes through the members in
    ascending id instead, so the leader had the first pick of every round and the last member took what was
    left; with gains that differ fifty-fold (the view gain) that member was sent across the building and back
    from round to round.

    Utility: `distances` (members' positions (M, 3), viewpoints (N, 3)) -> (M, N) metres, by default the
    Euclidean ones (the agent passes the way through its map: `ExplorationGrid.travel_distances`), from
    positions to viewpoints, d_others over the other members of
    `positions` at their current positions; times current_bonus when the candidate's viewpoint is within
    keep_radius of the member's current target, divided by it when the candidate is another member's current
    target (so drones keep their targets instead of swapping them between rounds), and times own_bonus when the
    member reported it. Scheduling lives for this round only. Members left without a candidate get None. Exact
    ties go to the lower id and to the first candidate in `merge_candidates`'s order, whatever order the input
    came in. A member is never given a candidate whose viewpoint lies within unreachable_radius of a viewpoint
    it could not plan a path to (`unreachable`): that candidate stays for the others. A candidate whose
    scheduled gain falls under `min_gain` is left for this round: what a drone already sent near it will see
    leaves it not worth another drone's trip (at the end of the office mission, three drones were sent one by
    one to leftover floor frontiers 2-4 m apart in the same far corner). Nor is a member sent to the candidate
    that another member will reach next, by way of its current target, and first (`_left_to_passing`): that one
    picks it up, and this one is free for something else or for home (at the end of a generated building, the
    leader flew 30 m and 35 s to a 7 m^3 leftover 5 m from where another drone was heading)."""
    members = sorted(positions)
    result: dict[int, Candidate | None] = {m: None for m in members}
    pool = sorted(candidates, key=order_key)
    if not pool or not members:
        return result
    views, points = as_vectors([c.viewpoint for c in pool]), as_vectors([c.point for c in pool])
    owners = np.array([c.owner for c in pool])
    busy = [(row, (current or {})[m]) for row, m in enumerate(members) if m in (current or {})]
    heading = as_vectors([target for _, target in busy])
    # one search from the members' positions to the candidates and to the busy members' own targets
    reach = np.asarray(distances(as_vectors([positions[m] for m in members]), np.vstack([views, heading])), dtype=float)
    dist = reach[:, : len(pool)]  # (members, cands)
    factor = np.ones_like(dist)  # the bonuses: they do not change within the round
    allowed = ~blocked_for(members, views, unreachable, unreachable_radius)
    for row, member in enumerate(members):
        target = None if current is None else current.get(member)
        factor[row] = _bonus(member, views, owners, target, current_bonus, own_bonus, keep_radius)
        for other, theirs in (current or {}).items():
            if other != member and other in positions:  # another drone is on its way there: leave it to it
                factor[row] = np.where(
                    within_radius(views, theirs, keep_radius), factor[row] / current_bonus, factor[row]
                )
    if busy and len(members) > 1:
        left = reach[[row for row, _ in busy], len(pool) + np.arange(len(busy))]  # each busy member's way to go
        via = left[:, None] + np.asarray(distances(heading, views), dtype=float)  # (busy, cands)
        allowed &= ~_left_to_passing([row for row, _ in busy], heading, via, dist, allowed, views, keep_radius)
    d_tot = dist.sum(axis=0)[None, :] - dist  # each member's d_tot: the other members' distances
    work = np.array([c.gain for c in pool], dtype=float)
    waiting = np.ones(len(members), dtype=bool)
    free = np.ones(len(pool), dtype=bool)
    while waiting.any() and free.any():
        u = _utilities(work[None, :], dist, d_tot, len(members) - 1, lam) * factor
        u = np.where(allowed & waiting[:, None] & free[None, :], u, -np.inf)
        row, best = map(int, np.unravel_index(int(np.argmax(u)), u.shape))  # row-major: ties go to the lower id first
        if not np.isfinite(u[row, best]):
            break  # the members still waiting cannot reach anything left
        result[members[row]] = pool[best]
        waiting[row], free[best] = False, False
        work = schedule_gain(work, points, pool[best].point, sigma)
        free &= work >= min_gain
    return result
