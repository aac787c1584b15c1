"""The exploration protocol as a pure core: what an explorer and a cluster leader decide, without a bus or a clock.

Like `swarm.patches.pull.PullScheduler`, the core takes inputs and returns what to do: messages in
(`on_report`, `on_assignment`), the map's frontiers and the drone's situation at every decision (`decide`), the
flight's outcomes (`looked_at`, `cannot_reach`), each with the time `now` (seconds, any monotonic clock); out come
`Effects`: messages to publish, whether the flight must drop its path, whether to decide again at once, and
events to log. `swarm.agent.exploration.Exploration` only pumps it (asyncio, the bus, the flight).

Roles (Mahdoui; docs/architecture.md, "Exploration"):
- explorer: reports its candidates, what it has looked at and what it could not reach to its leader every
  decision; takes the leader's assignment; with none for `explorer_timeout_s` (tau, from its first report to this
  leader) it picks its own target (Eq. 3.3).
- leader: merges every fresh report with its own candidates, drops what its fused map already knows, what a
  drone already looked at in that direction, and what no member can reach, assigns the rest (best pair first,
  gain scheduling) and publishes the assignment.
- uncoordinated: every drone is its own leader over its own candidates.

Invariants:
- A look is a (viewpoint, point) pair: a candidate is exhausted by a look from within `visited_radius_m` of its
  viewpoint facing within LOOK_HALF_ANGLE_DEG of its direction (or any look there when its point is straight
  above or below its viewpoint: turning does not change what is seen). Looking from a spot already visited in a
  direction not yet looked at is a valid target: a drone that took off in a small room has every viewpoint in
  that room, and exhaustion by position alone ended a mission at 14 % after the first look.
- A viewpoint this drone could not plan a path to is kept from it for UNREACHABLE_RETRY_S; after
  UNREACHABLE_GIVE_UP failures it is kept from it until the map near it changes (its unknown volume moves by
  MAP_CHANGE_M3). Unreachable targets are personal: the leader gives them to another member, and a candidate
  counts as given up for the cluster only when no member may be sent there (`given_up` says which and why).
- Failures from a pocket (`Situation.in_pocket`: the drone's own cell is shut in by its map) are not counted: the
  drone gets out first.
- The leader checks what it is told (docs/security.md, "The leader checks what it is told"): a member's
  candidate whose viewpoint lies outside the mission volume (`ReportLimits.volume`, grown by `margin_m`) or whose
  point lies farther out than that plus LOOK_AHEAD_M is dropped, and so is a look from outside it; a gain above
  the most a view can hold (`ReportLimits.max_gain_m3`) is clamped to it, a non-finite or negative one drops its
  candidate; with shared maps each member's OWN_GAIN_PER_MEMBER best candidates are ranked by the smaller of the
  reported gain and the gain the leader's own fused map gives them, the rest by no more than the least of those;
  a member's look counts only within `visited_radius_m + arrive_tolerance_m` of its heartbeat track
  (`Situation.tracks`), so a member can exhaust candidates only along where it flew. Each kind of input left out
  is counted (`rejected`, the summary's `exploration_rejected`), once per report the leader uses. An explorer
  does not fly an assignment outside the mission volume.
- Done means the cluster's fused map has no reachable frontier left with gain: the leader's merged set minus what
  no member can reach is empty while the leader is not in a pocket, and it stays so for a whole loop in which
  every member reported afresh, in pockets none of them (a member's pocket is believed for POCKET_TRUST_LOOPS
  loops; patches in flight can hide frontiers for a moment), and the leader's map holds every patch its members
  hold (`Situation.patches_to_come`, believed for as long as pockets: a member announcing patches it never serves
  must not hold the cluster for ever). Only
  then does the leader publish `done`, and again every decision, so that a lost message or a late member still
  hears it.
- `left_out_at` is when a decision for this drone (its leader's assignment, or its own as leader or on its own)
  last found no target for it: not a wait between two targets but nothing to do, so an idle drone heads home at
  once instead of after `idle_home_s` (`swarm.agent.exploration`). `rounds_since(t)` counts the decisions for this
  drone since `t`: on a loaded machine a round can take longer than `idle_home_s`, and a drone waiting for one is
  not idle (`should_head_home`).
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

import numpy as np
from scipy.spatial import cKDTree

from swarm.bus.codec import WireMessage
from swarm.config import ExploreSettings, SwarmConfig, Vec3
from swarm.explore.frontiers import LOOK_AHEAD_M, Frontier, ViewModel
from swarm.roles.assignment import Candidate, assign_targets, merge_candidates, remove_overlapped
from swarm.roles.messages import MAX_CANDIDATES, MAX_VISITED, FrontierReport, TargetAssignment, as_points
from swarm.roles.tours import assign_tours

KEEP_RADIUS_M = 1.0  # a new target this close to the current one is the same target: no interruption
REPORT_FRESH_LOOPS = 3.0  # a member's report older than this many loops is ignored by the leader
# Liveness against a member that lies (docs/security.md): an honest drone leaves a pocket within a few loops (it
# flies out of it, swarm.agent.exploration), so once the cluster has had no candidate for POCKET_TRUST_LOOPS loops,
# members' pockets no longer keep it from being done (counted from when the candidates ran out, not per pocket: a
# liar interleaving pocket reports with its agent's honest ones would restart a per-pocket clock). A member's
# arrivals wake the leader at most once per ARRIVAL_WAKE_GAP_S (an honest drone arrives once per target, seconds
# apart), so reports at the bus's rate cannot make it decide at that rate.
POCKET_TRUST_LOOPS = 10
ARRIVAL_WAKE_GAP_S = 1.0
UNREACHABLE_RETRY_S = 30.0  # a viewpoint this drone could not plan a path to is not given to it again this long
UNREACHABLE_GIVE_UP = 3  # ... and after this many failures not until the map near it changes
MAP_CHANGE_M3 = 0.3  # the unknown volume round a given-up viewpoint moved this much: the map changed, try again
LOOK_HALF_ANGLE_DEG = 30.0  # a look covers candidates this far either side of its direction (a third of the FOV)
BLIND_M = 0.1  # a point this close to straight above or below its viewpoint has no direction to look in
ROUNDS_KEPT = 4  # times of the latest decisions for this drone kept, for `rounds_since`
OWN_GAIN_PER_MEMBER = 32  # a member's candidates the leader ray-casts on its own map per decision (0.35 ms each)

Source = Literal["leader", "self"]


@dataclass
class Target:
    viewpoint: Vec3
    point: Vec3
    source: Source
    gain: float | None = None  # m^3, as the decider saw it (None: another leader's assignment, gains not sent)


@dataclass(frozen=True)
class GivenUp:
    """A frontier nobody will be sent to, and why (the report lists them)."""

    viewpoint: Vec3
    point: Vec3
    reason: str
    at_s: float


class MapQueries(Protocol):
    """What the core asks of the drone's fused map (an `ExplorationGrid`)."""

    def gain_at(self, points: np.ndarray) -> np.ndarray: ...

    def view_gain(self, viewpoints: np.ndarray, points: np.ndarray) -> np.ndarray: ...

    def is_frontier_near(self, point: Vec3, radius: float) -> bool: ...

    def travel_distances(self, starts: np.ndarray, goals: np.ndarray) -> np.ndarray: ...

    def travel_between(self, points: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class ReportLimits:
    """What a member's report can hold: where its viewpoints can be, and the most unknown volume a gain can say.
    The defaults check nothing (a core built without a mission, as in tests of other rules)."""

    volume: tuple[Vec3, Vec3] | None = None  # the mission volume (min, max corners)
    margin_m: float = 0.0  # planning cells reach past the volume by up to a cell (from_config grows it by one)
    max_gain_m3: float = math.inf

    @classmethod
    def from_config(cls, config: SwarmConfig) -> ReportLimits:
        """The mission volume, and the gain bound of `explore.gain_model`: a view sees at most its frustum's
        volume to the camera's range (plus a grid cell: the ray samples' last interval), a box gain at most its
        cube; neither more than the mission volume."""
        res = config.mapping.planning_resolution_m
        volume = config.mission.volume
        if config.explore.gain_model == "view":
            _, solid = ViewModel.from_camera(config.camera).rays()
            bound = float(solid.sum()) * (config.camera.max_range_m + res) ** 3 / 3.0
        else:
            bound = (2 * round(config.explore.gain_radius_m / res) + 1) ** 3 * res**3
        if volume is None:
            return cls(None, res, bound)
        bound = min(bound, math.prod(hi - lo for lo, hi in zip(volume.min, volume.max)))
        return cls((volume.min, volume.max), res, bound)

    def inside(self, points: np.ndarray, extra_m: float = 0.0) -> np.ndarray:
        """(N,) which of (N, 3) points lie in the volume grown by margin_m + extra_m (all, without a volume)."""
        rows = np.asarray(points, dtype=float).reshape(-1, 3)
        if self.volume is None:
            return np.ones(len(rows), dtype=bool)
        grow = self.margin_m + extra_m
        lo, hi = np.asarray(self.volume[0], dtype=float) - grow, np.asarray(self.volume[1], dtype=float) + grow
        inside: np.ndarray = np.all((rows >= lo) & (rows <= hi), axis=1)
        return inside


@dataclass
class Situation:
    """One decision's inputs besides messages: where the drone is, whom it is with, what its map shows."""

    here: Vec3
    leader: int | None
    cluster: list[int]
    positions: dict[int, Vec3]  # the other members' latest positions (heartbeats)
    frontiers: list[Frontier]
    map: MapQueries
    in_pocket: bool = False  # this drone's own cell is shut in by its map: nothing is unreachable from here
    tracks: dict[int, np.ndarray] = field(default_factory=dict)  # (N, 3) each member's heartbeat track
    patches_to_come: int = 0  # patches a member of the cluster holds that this drone's map does not have yet
    home: Vec3 | None = None  # where this drone flies when the cluster is done (None: it lands where it is)


@dataclass
class Effects:
    """What the glue must do after a call: publish, interrupt the flight, decide again now, log."""

    publish: list[WireMessage] = field(default_factory=list)
    retarget: bool = False
    wake: bool = False
    events: list[tuple[str, dict[str, Any]]] = field(default_factory=list)

    def log(self, event: str, **fields: Any) -> None:
        self.events.append((event, fields))


@dataclass
class _Unreachable:
    viewpoint: Vec3
    at_s: float
    unknown_m3: float  # the box gain round it when it failed: when that moves, the map changed near it


@dataclass
class _Checked:
    """A member's report as the leader uses it: what passed its checks."""

    report: FrontierReport
    candidates: list[Candidate]
    looks: list[tuple[Vec3, Vec3]]


REJECTED_KINDS = (
    "candidate_outside_volume",  # a candidate's viewpoint or point outside the mission volume
    "gain_invalid",  # non-finite or negative (the wire already refuses these)
    "gain_clamped",  # above the most a view can see
    "visited_outside_volume",
    "visited_off_track",  # a look far from every heartbeat position the member sent
    "assignment_outside_volume",  # an explorer's: a target its leader sent outside the mission volume
    "arrival_wake_limited",  # an arrival within ARRIVAL_WAKE_GAP_S of the member's last: no extra decision
    "pocket_distrusted",  # done although a member says it is in a pocket: POCKET_TRUST_LOOPS loops without candidates
    "patches_never_came",  # done although a member lists patches this map lacks: as long a wait as for a pocket
)


class ExplorationCore:
    def __init__(
        self, settings: ExploreSettings, drone: int, epoch: int, now: float, limits: ReportLimits | None = None
    ) -> None:
        self.settings = settings
        self.limits = limits or ReportLimits()
        self.rejected = dict.fromkeys(REJECTED_KINDS, 0)
        self._checked: dict[int, _Checked] = {}
        self.strategy = settings.strategy
        self.id = drone
        self.epoch = epoch
        self.target: Target | None = None
        self.looks: list[tuple[Vec3, Vec3]] = []  # (viewpoint, point) of every look this drone took
        self.unreachable: list[_Unreachable] = []
        self.given_up: list[GivenUp] = []
        self.own: list[Candidate] = []
        self.done = False
        self.done_reason = ""
        self.reports: dict[int, tuple[float, FrontierReport]] = {}
        self.last_assignment: dict[int, tuple[float, TargetAssignment]] = {}  # leader -> latest
        self.following: tuple[int | None, float] = (None, 0.0)  # the leader we report to, since when
        self.assigned_current: dict[int, Vec3] = {}  # as leader: each member's current target
        self.arrived = False
        self.in_pocket = False
        self.round = 0
        self.report_seq = 0
        self.empty_since: float | None = None  # as leader: when the cluster's candidates first ran out
        self.left_out_at: float | None = None  # when a decision for this drone last found nothing for it
        self._rounds: deque[float] = deque(maxlen=ROUNDS_KEPT)  # when the latest decisions for this drone came
        self._woke_at: dict[int, float] = {}  # as leader: member -> when its arrival last woke a decision
        self.loops = 0
        self.targets_assigned = 0
        self.targets_self_selected = 0
        self.started = now

    @property
    def visited(self) -> list[Vec3]:
        return [v for v, _ in self.looks]

    def rounds_since(self, t: float) -> int:
        """Decisions for this drone since `t` (up to ROUNDS_KEPT): its leader's rounds heard, and its own as
        leader, on its own, or as an explorer whose leader went quiet."""
        return sum(1 for at in list(self._rounds) if at >= t)  # a copy: list() takes it without a thread switch

    # -- messages in ------------------------------------------------------------------------------------------

    def on_report(self, now: float, sender: int | None, report: FrontierReport, leader: int | None) -> Effects:
        """A member's report (`sender` from its key, None if it names no drone): kept for the leader's next
        decision; an arrival wakes it."""
        effects = Effects()
        if sender != report.id or report.id == self.id:
            return effects
        self.reports[report.id] = (now, report)
        if report.arrived and leader == self.id:
            if now - self._woke_at.get(report.id, -math.inf) < ARRIVAL_WAKE_GAP_S:
                self.rejected["arrival_wake_limited"] += 1
            else:
                self._woke_at[report.id] = now
                effects.wake = True
        return effects

    def on_assignment(
        self, now: float, sender: int | None, assignment: TargetAssignment, leader: int | None
    ) -> Effects:
        effects = Effects()
        if sender != assignment.leader or assignment.leader == self.id:
            return effects
        self.last_assignment[assignment.leader] = (now, assignment)
        if assignment.leader != leader or self.done:
            return effects  # not (or no longer) our leader: ignore
        self._rounds.append(now)
        if assignment.done:
            self.finish(effects, f"leader {assignment.leader} declared the cluster done")
            return effects
        mine = assignment.target_of(self.id)
        if mine is None and self.id in assignment.members:
            self.left_out_at = now
        if mine is not None and not (
            self.limits.inside(np.asarray([mine[0]])).all() and self.limits.inside(np.asarray([mine[1]]), LOOK_AHEAD_M)
        ):
            self.rejected["assignment_outside_volume"] += 1
            effects.log("assignment_outside_volume", leader=assignment.leader, viewpoint=_r(mine[0]))
        elif mine is not None:
            self.set_target(effects, Target(mine[0], mine[1], "leader"))
        return effects

    # -- decisions ------------------------------------------------------------------------------------------

    def decide(self, now: float, situation: Situation) -> Effects:
        effects = Effects()
        if self.done and situation.leader != self.id:
            return effects
        self.loops += 1
        self.in_pocket = situation.in_pocket
        self._forget_unreachable(situation.map, effects)
        self.own = self._candidates(situation.frontiers)
        self._drop_explored_target(situation.map, effects)
        if self.strategy == "uncoordinated":
            self._rounds.append(now)
            self._choose_own(now, effects, situation)
        elif situation.leader == self.id:
            self._rounds.append(now)
            self._lead(now, situation, effects)
        else:
            self._explore(now, situation, effects)
        self.arrived = False
        return effects

    def _candidates(self, frontiers: Sequence[Frontier]) -> list[Candidate]:
        own = [Candidate(f.viewpoint, f.point, f.gain, self.id) for f in frontiers[:MAX_CANDIDATES]]
        return [c for c in own if not _looked_at(c, self.looks, self.settings.visited_radius_m)]

    def _drop_explored_target(self, grid: MapQueries, effects: Effects) -> None:
        if self.target is not None and not grid.is_frontier_near(self.target.point, self.settings.cluster_size_m):
            effects.log("target_explored", target=_r(self.target.viewpoint))
            self.target = None
            self.arrived = True  # ask for a new one now
            effects.retarget = True

    def _choose_own(self, now: float, effects: Effects, situation: Situation) -> None:
        """Eq. 3.3 on this drone's own candidates (uncoordinated, or an explorer whose leader went quiet)."""
        if self.done:
            return
        blocked = self._blocked_for_me(now)
        reachable = [c for c in self.own if not _near(c.viewpoint, blocked, self.settings.visited_radius_m)]
        choice = assign_targets(
            reachable,
            {self.id: situation.here},
            lam=self.settings.utility_lambda,
            sigma=self.settings.sigma_m,
            current=self._current(),
            current_bonus=self.settings.current_target_bonus,
            keep_radius=KEEP_RADIUS_M,
            distances=situation.map.travel_distances,
        ).get(self.id)
        if choice is not None:
            self.empty_since = None
            self.set_target(effects, Target(choice.viewpoint, choice.point, "self", choice.gain))
            return
        self.left_out_at = now
        self._record_given_up(now, [c for c in self.own if c not in reachable], "unreachable by this drone")
        if self.strategy == "uncoordinated" or situation.leader == self.id:
            self._maybe_done(now, effects, situation, "no frontier left in this drone's map", members=[self.id])

    def _explore(self, now: float, situation: Situation, effects: Effects) -> None:
        self.report_seq += 1
        effects.publish.append(
            FrontierReport(
                id=self.id,
                epoch=self.epoch,
                seq=self.report_seq,
                position=situation.here,
                viewpoints=as_points([c.viewpoint for c in self.own]),
                points=as_points([c.point for c in self.own]),
                gains=np.asarray([c.gain for c in self.own], dtype=np.float32),
                visited=as_points(self.visited[-MAX_VISITED:]),
                looked_at=as_points([p for _, p in self.looks[-MAX_VISITED:]]),
                unreachable=as_points(self._blocked_for_me(now)[-MAX_VISITED:]),
                arrived=self.arrived,
                in_pocket=situation.in_pocket,
                home=situation.home,
            )
        )
        leader = situation.leader
        if self.following[0] != leader:
            # tau runs from our first report to this leader: before it, the leader had nothing to assign us
            self.following = (leader, now)
        heard = self.last_assignment.get(leader) if leader is not None else None
        waited = now - max(self.following[1], heard[0] if heard else 0.0)
        if waited > self.settings.explorer_timeout_s and (self.target is None or self.target.source == "self"):
            self._rounds.append(now)
            self._choose_own(now, effects, situation)

    def _lead(self, now: float, situation: Situation, effects: Effects) -> None:
        members = situation.cluster
        if self.done:
            effects.publish.append(self._done_message(members))  # again: a lost message or a late member hears it
            return
        fresh_after = now - REPORT_FRESH_LOOPS * self.settings.loop_s
        reports = {k: r for k, (t, r) in self.reports.items() if k in members and t >= fresh_after}
        checked = {k: self._check(r, situation.tracks.get(k)) for k, r in reports.items()}
        received = {k: c.candidates for k, c in checked.items()}
        looks = [*self.looks, *(look for c in checked.values() for look in c.looks)]
        radius = self.settings.visited_radius_m
        if self.strategy == "frontier-only":
            pooled = remove_overlapped({self.id: self.own, **received})
            merged = merge_candidates(
                pooled,
                {},
                gain_now=None,
                min_gain=0.0,
                exhausted=[],
                exhausted_radius=radius,
                merge_radius=self.settings.cluster_size_m,
            )
        else:
            merged = merge_candidates(
                self.own,
                {k: self._own_gains(c, situation.map) for k, c in received.items()},
                gain_now=situation.map.gain_at,
                min_gain=self.settings.min_gain_m3,
                exhausted=[],
                exhausted_radius=radius,
                merge_radius=self.settings.cluster_size_m,
            )
        merged = [c for c in merged if not _looked_at(c, looks, radius)]
        positions = {self.id: situation.here}
        positions.update({k: p for k, p in situation.positions.items() if k in members and k != self.id})
        blocked = {self.id: self._blocked_for_me(now), **{k: _points(r.unreachable) for k, r in reports.items()}}
        assignable = [c for c in merged if any(not _near(c.viewpoint, blocked.get(k, []), radius) for k in positions)]
        self._record_given_up(
            now, [c for c in merged if c not in assignable], f"unreachable by every member of {sorted(positions)}"
        )
        self.round += 1
        if not assignable:
            self.left_out_at = now
            self._maybe_done(
                now,
                effects,
                situation,
                f"leader {self.id}: no reachable frontier left in cluster {members}",
                members,
                reports,
            )
            if not self.done:  # a round with nothing for anyone: an idle member heads home (`left_out_at`)
                effects.publish.append(
                    TargetAssignment(leader=self.id, epoch=self.epoch, round=self.round, members=members)
                )
            return
        self.empty_since = None
        homes = {
            k: r.home for k, r in reports.items() if r.home is not None and self.limits.inside(np.asarray(r.home)).all()
        }
        if situation.home is not None:
            homes[self.id] = situation.home
        rule, choice = self._assign(assignable, positions, blocked, homes, situation.map)
        assigned = {k: c for k, c in choice.items() if c is not None}
        self.assigned_current = {k: c.viewpoint for k, c in assigned.items()}
        effects.log(
            "assignment",
            round=self.round,
            candidates=len(assignable),
            rule=rule,
            gains={k: round(c.gain, 2) for k, c in assigned.items()},
        )
        drones = sorted(assigned)
        effects.publish.append(
            TargetAssignment(
                leader=self.id,
                epoch=self.epoch,
                round=self.round,
                members=members,
                drones=drones,
                viewpoints=as_points([assigned[k].viewpoint for k in drones]),
                points=as_points([assigned[k].point for k in drones]),
            )
        )
        mine = assigned.get(self.id)
        if mine is not None:
            self.set_target(effects, Target(mine.viewpoint, mine.point, "leader", mine.gain))
        else:
            self.left_out_at = now

    def _assign(
        self,
        candidates: list[Candidate],
        positions: dict[int, Vec3],
        blocked: dict[int, list[Vec3]],
        homes: dict[int, Vec3],
        grid: MapQueries,
    ) -> tuple[str, dict[int, Candidate | None]]:
        """The rule used ("utility" or "tours") and one candidate (or None) per member: by utility
        (`assign_targets`) or by tours (`assign_tours`), as `explore.assignment` says."""
        s = self.settings
        current = {k: v for k, v in self.assigned_current.items() if k in positions}
        tail = s.assignment == "tail-tours" and max((c.gain for c in candidates), default=0.0) < s.tail_gain_m3
        if s.assignment == "tours" or tail:
            return "tours", assign_tours(
                candidates,
                positions,
                current=current,
                current_bonus=s.current_target_bonus,
                keep_radius=KEEP_RADIUS_M,
                unreachable=blocked,
                unreachable_radius=s.visited_radius_m,
                min_gain=self._trip_gain(),
                distances=grid.travel_distances,
                between=grid.travel_between,
                homes=homes,
            )
        return "utility", assign_targets(
            candidates,
            positions,
            lam=s.utility_lambda,
            sigma=s.sigma_m,
            current=current,
            current_bonus=s.current_target_bonus,
            own_bonus=s.own_frontier_bonus,
            keep_radius=KEEP_RADIUS_M,
            unreachable_radius=s.visited_radius_m,
            unreachable=blocked,
            min_gain=self._trip_gain(),
            distances=grid.travel_distances,
        )

    def _check(self, report: FrontierReport, track: np.ndarray | None) -> _Checked:
        """The report's candidates and looks that pass the leader's checks (the module docstring), counted once
        per report: a report is checked when the leader first uses it, against the track heard by then."""
        known = self._checked.get(report.id)
        if known is not None and known.report is report:
            return known
        limits, count = self.limits, self.rejected
        gains = np.asarray(report.gains, dtype=float)
        valid = np.isfinite(gains) & (gains >= 0.0)
        inside = limits.inside(report.viewpoints) & limits.inside(report.points, LOOK_AHEAD_M)
        count["gain_invalid"] += int(np.count_nonzero(~valid))
        count["candidate_outside_volume"] += int(np.count_nonzero(valid & ~inside))
        keep = valid & inside
        count["gain_clamped"] += int(np.count_nonzero(keep & (gains > limits.max_gain_m3)))
        candidates = [
            Candidate(_vec(v), _vec(p), min(float(g), limits.max_gain_m3), report.id)
            for v, p, g, k in zip(report.viewpoints, report.points, gains, keep)
            if k
        ]
        looks = _report_looks(report)
        eyes = np.asarray([v for v, _ in looks], dtype=float).reshape(-1, 3)
        placed = limits.inside(eyes)
        count["visited_outside_volume"] += int(np.count_nonzero(~placed))
        reach = self.settings.visited_radius_m + self.settings.arrive_tolerance_m
        near = _near_track(eyes, track, reach)
        count["visited_off_track"] += int(np.count_nonzero(placed & ~near))
        checked = self._checked[report.id] = _Checked(
            report, candidates, [look for look, ok in zip(looks, placed & near) if ok]
        )
        return checked

    def _own_gains(self, candidates: list[Candidate], grid: MapQueries) -> list[Candidate]:
        """A member's candidates with each gain no more than the leader's own map gives it: ray cast (the view
        gain) for the OWN_GAIN_PER_MEMBER best as reported, the rest no more than the least of those (a member
        that reports hundreds must not stall the leader's loop). The box gain is cheap: every one is computed."""
        if not candidates:
            return []
        order = sorted(candidates, key=lambda c: -c.gain)
        if self.settings.gain_model == "view":
            head = order[:OWN_GAIN_PER_MEMBER]
            own = np.asarray(
                grid.view_gain(_array([c.viewpoint for c in head]), _array([c.point for c in head])), dtype=float
            )
        else:
            head = order
            own = np.asarray(grid.gain_at(_array([c.point for c in head])), dtype=float)
        own = np.where(np.isfinite(own) & (own >= 0.0), own, 0.0).reshape(len(head))
        floor = float(own.min())
        gains = [*own.tolist(), *([floor] * (len(order) - len(head)))]
        return [dataclasses.replace(c, gain=min(c.gain, g)) for c, g in zip(order, gains)]

    def _trip_gain(self) -> float:
        """The least gain worth a trip, in the unit of the candidates' gains."""
        s = self.settings
        return s.min_view_gain_m3 if s.gain_model == "view" else s.min_gain_m3

    def _maybe_done(
        self,
        now: float,
        effects: Effects,
        situation: Situation,
        reason: str,
        members: list[int],
        reports: dict[int, FrontierReport] | None = None,
    ) -> None:
        """No candidate left: done once that has held for a loop in which every member reported afresh, and
        nobody is in a pocket (see the module docstring)."""
        if self.target is not None or situation.in_pocket:
            self.empty_since = None
            return
        if self.empty_since is None:
            self.empty_since = now
            return
        others = [k for k in members if k != self.id]
        fresh = all(k in self.reports and self.reports[k][0] > self.empty_since for k in others)
        pockets = [k for k in others if k in self.reports and self.reports[k][1].in_pocket]
        trusted = now - self.empty_since < POCKET_TRUST_LOOPS * self.settings.loop_s
        waiting = (pockets or situation.patches_to_come > 0) and trusted
        if fresh and not waiting and now - self.empty_since >= self.settings.loop_s:
            if pockets:
                self.rejected["pocket_distrusted"] += 1
            if situation.patches_to_come > 0:
                self.rejected["patches_never_came"] += 1
            self.finish(effects, reason)
            if situation.leader == self.id and self.strategy != "uncoordinated":
                effects.publish.append(self._done_message(members))

    def _done_message(self, members: list[int]) -> TargetAssignment:
        return TargetAssignment(leader=self.id, epoch=self.epoch, round=self.round, members=members, done=True)

    def _current(self) -> dict[int, Vec3]:
        return {self.id: self.target.viewpoint} if self.target is not None else {}

    def set_target(self, effects: Effects, target: Target) -> bool:
        """Take a new target; False when it is the current one (kept without interrupting the flight)."""
        current = self.target
        if current is not None and _distance(current.viewpoint, target.viewpoint) < KEEP_RADIUS_M:
            # Update the same object: the flight knows its target by identity, and a new object at every loop meant
            # it never counted as reached (no dwell, never done, the same spot assigned again: a silent livelock).
            current.point, current.source = target.point, target.source
            return False
        self.target = target
        if target.source == "self":
            self.targets_self_selected += 1
        else:
            self.targets_assigned += 1
        effects.log(
            "target",
            viewpoint=_r(target.viewpoint),
            point=_r(target.point),
            source=target.source,
            gain=None if target.gain is None else round(target.gain, 2),
            replaces=_r(current.viewpoint) if current is not None else None,
        )
        effects.retarget = True
        return True

    def finish(self, effects: Effects, reason: str) -> None:
        if not self.done:
            self.done, self.done_reason = True, reason
            effects.log(
                "exploration_done", reason=reason, loops=self.loops, given_up=[_given_up_dict(g) for g in self.given_up]
            )
        self.target = None
        effects.retarget = True

    # -- the flight's outcomes --------------------------------------------------------------------------------

    def looked_at(self, target: Target) -> Effects:
        """A target reached (its look is starting): it counts as looked at, and the cluster assigns again now."""
        self.looks.append((target.viewpoint, target.point))
        self.arrived = True
        return Effects(wake=True)

    def look_finished(self, target: Target) -> None:
        if self.target is target:
            self.target = None

    def cannot_reach(self, now: float, target: Target, grid: MapQueries) -> Effects:
        """No path to the target's viewpoint in this drone's map (not from a pocket: the glue gets out of those
        first): kept from this drone for UNREACHABLE_RETRY_S, after UNREACHABLE_GIVE_UP failures until the map
        near it changes. The others may reach it."""
        effects = Effects(wake=True)
        unknown = float(grid.gain_at(np.asarray([target.viewpoint]))[0])
        self.unreachable.append(_Unreachable(target.viewpoint, now, unknown))
        failures = self._failures(target.viewpoint)
        if failures >= UNREACHABLE_GIVE_UP:
            effects.log("unreachable_given_up", viewpoint=_r(target.viewpoint), failures=failures)
        if self.target is target:
            self.target = None
        self.arrived = True
        return effects

    def _failures(self, viewpoint: Vec3) -> int:
        return sum(_distance(u.viewpoint, viewpoint) <= self.settings.visited_radius_m for u in self.unreachable)

    def _blocked_for_me(self, now: float) -> list[Vec3]:
        """Viewpoints not to be given to this drone: failed recently, or failed too often (until the map moves)."""
        since = now - UNREACHABLE_RETRY_S
        out: list[Vec3] = []
        for u in self.unreachable:
            if u.at_s >= since or self._failures(u.viewpoint) >= UNREACHABLE_GIVE_UP:
                if not _near(u.viewpoint, out, 1e-6):
                    out.append(u.viewpoint)
        return out

    def _forget_unreachable(self, grid: MapQueries, effects: Effects) -> None:
        """Failures whose surroundings the map has changed since are forgotten: the way there may be open now."""
        if not self.unreachable:
            return
        unknown = grid.gain_at(np.asarray([u.viewpoint for u in self.unreachable]))
        changed = np.abs(unknown - np.array([u.unknown_m3 for u in self.unreachable])) >= MAP_CHANGE_M3
        for u in (u for u, c in zip(self.unreachable, changed) if c):
            effects.log("unreachable_retry", viewpoint=_r(u.viewpoint))
        self.unreachable = [u for u, c in zip(self.unreachable, changed) if not c]

    def _record_given_up(self, now: float, candidates: Sequence[Candidate], reason: str) -> None:
        """What nobody will be sent to as of this decision (a snapshot: blocks expire and maps change)."""
        since = {g.viewpoint: g.at_s for g in self.given_up}
        at = round(now - self.started, 1)
        self.given_up = [GivenUp(c.viewpoint, c.point, reason, since.get(c.viewpoint, at)) for c in candidates]

    def summary(self) -> dict[str, Any]:
        return {
            "strategy": self.strategy,
            "targets_assigned": self.targets_assigned,
            "targets_self_selected": self.targets_self_selected,
            "exploration_loops": self.loops,
            "exploration_done": self.done,
            "exploration_done_reason": self.done_reason,
            "targets_visited": len(self.looks),
            "frontiers_given_up": [_given_up_dict(g) for g in self.given_up],
            "exploration_rejected": dict(self.rejected),
        }


def _looked_at(candidate: Candidate, looks: Sequence[tuple[Vec3, Vec3]], radius: float) -> bool:
    """A look from within `radius` of the candidate's viewpoint covers it: facing its way, or any way when its
    point is straight above or below the viewpoint."""
    if not looks:
        return False
    eyes = np.asarray([v for v, _ in looks], dtype=float)
    near = np.linalg.norm(eyes - np.asarray(candidate.viewpoint, dtype=float), axis=1) <= radius
    if not near.any():
        return False
    wanted = np.subtract(candidate.point, candidate.viewpoint)[:2]
    if np.hypot(*wanted) < BLIND_M:
        return True
    seen = np.asarray([p for _, p in looks], dtype=float)[near, :2] - eyes[near, :2]
    level = np.hypot(seen[:, 0], seen[:, 1]) >= BLIND_M  # a look straight up or down faced no way in particular
    angle = np.abs(np.angle(np.exp(1j * (np.arctan2(seen[:, 1], seen[:, 0]) - math.atan2(wanted[1], wanted[0])))))
    return bool(np.any(~level | (angle <= math.radians(LOOK_HALF_ANGLE_DEG))))


def _near(point: Vec3, centres: Sequence[Vec3] | np.ndarray, radius: float) -> bool:
    if len(centres) == 0:
        return False
    return bool(np.any(np.linalg.norm(np.asarray(centres, dtype=float) - np.asarray(point), axis=1) <= radius))


def _near_track(eyes: np.ndarray, track: np.ndarray | None, radius: float) -> np.ndarray:
    """(N,) which eyes lie within radius of a point of the track (none, without one)."""
    if track is None or len(track) == 0 or len(eyes) == 0:
        return np.zeros(len(eyes), dtype=bool)
    distance, _ = cKDTree(np.asarray(track, dtype=float).reshape(-1, 3)).query(eyes, distance_upper_bound=radius)
    near: np.ndarray = np.isfinite(distance)
    return near


def _array(points: Sequence[Vec3]) -> np.ndarray:
    return np.asarray(points, dtype=float).reshape(-1, 3)


def _report_looks(report: FrontierReport) -> list[tuple[Vec3, Vec3]]:
    """A report's looks; a sender that names no points (an older agent) looked from there every way."""
    if len(report.looked_at) != len(report.visited):
        return [(_vec(v), _vec(v)) for v in report.visited]
    return [(_vec(v), _vec(p)) for v, p in zip(report.visited, report.looked_at)]


def _points(rows: np.ndarray) -> list[Vec3]:
    return [_vec(r) for r in rows]


def _given_up_dict(g: GivenUp) -> dict[str, Any]:
    return {"viewpoint": _r(g.viewpoint), "point": _r(g.point), "reason": g.reason, "at_s": g.at_s}


def _vec(row: np.ndarray) -> Vec3:
    return float(row[0]), float(row[1]), float(row[2])


def _distance(a: Vec3, b: Vec3) -> float:
    return float(np.linalg.norm(np.subtract(a, b)))


def _r(p: Vec3) -> list[float]:
    return [round(float(v), 2) for v in p]
