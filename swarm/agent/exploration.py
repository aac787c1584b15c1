"""One drone's exploration: the decision loop (frontiers, roles, targets) and the mission that flies to them.

Every `explore.loop_s` (r), and at once when a drone of the cluster reaches its target, the agent computes its
frontiers from its fused map (`MappingTask.explore_view`). Then, by strategy (docs/architecture.md,
"Exploration"):

- **coordinated** (Mahdoui): an explorer sends its candidates to its leader (`FrontierReport`); the leader
  merges them with its own, drops those its fused map already knows and those next to a spot a drone already
  looked at, assigns every member a target with the utility and gain scheduling (`swarm.roles.assignment`), and
  publishes the `TargetAssignment`. An explorer with no assignment from its leader for `explorer_timeout_s`
  (tau), counted from its first report to that leader, picks its own. A leader with no candidate left three
  loops in a row declares its cluster done.
- **uncoordinated:** every drone picks the best of its own candidates (Eq. 3.3); maps are still shared.
- **frontier-only** (the thesis's original): as coordinated, but patches are not shared, so the leader removes
  the candidates inside another member's explored region by the scan-line overlap test instead.

The flight side (`fly`) plans a path on the latest grid to the current target's viewpoint, flies it (the
decision loop interrupts it when the target changes or the path becomes blocked), turns to the frontier point
for `dwell_s`, and reports that it arrived. When the mission is done it returns above its take-off point.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from swarm.aio import wait_event
from swarm.agent.flight import Flight
from swarm.agent.mapping import MappingTask
from swarm.bus.bridge import AsyncBus
from swarm.config import SwarmConfig, Vec3
from swarm.explore.frontiers import ExplorationGrid, Frontier
from swarm.explore.planner import NoPathError, path_is_free, plan_path
from swarm.roles.assignment import Candidate, assign_targets, merge_candidates, remove_overlapped
from swarm.roles.membership import PeerTable
from swarm.roles.messages import MAX_CANDIDATES, MAX_VISITED, FrontierReport, TargetAssignment, as_points

EMPTY_ROUNDS_FOR_DONE = 3  # a transient empty frontier set (a map update in flight) must not end the mission
KEEP_RADIUS_M = 1.0  # a new target this close to the current one is the same target: no interruption
REPORT_FRESH_LOOPS = 3.0  # a member's report older than this many loops is ignored by the leader
PLAN_EXPANSIONS = 150_000
STATUS_EVERY_LOOPS = 10
RETURN_ATTEMPTS = 3  # a drone that had to give way too long on its way home plans again
WAIT_FOR_TARGET_S = 0.5
IDLE_TURN_DEG = 45.0
UNREACHABLE_RETRY_S = 30.0  # a viewpoint this drone could not plan a path to is not given to it again this long
UNREACHABLE_GIVE_UP = 3  # ... and after this many failures it counts as visited: nobody is sent there again


@dataclass
class Target:
    viewpoint: Vec3
    point: Vec3
    source: str  # "leader" or "self"


class Exploration:
    def __init__(
        self,
        config: SwarmConfig,
        epoch: int,
        bus: AsyncBus,
        peers: PeerTable,
        mapping: MappingTask,
        position: Callable[[], Vec3],
        home: Callable[[], Vec3 | None],
        top_z: float,
        log: Callable[..., None],
        obstacles: Callable[[], list[Vec3]] = list,
    ) -> None:
        self.config = config
        self.settings = config.explore
        self.strategy = config.explore.strategy
        self.id = config.agent.id
        self.epoch = epoch
        self.bus = bus
        self.peers = peers
        self.mapping = mapping
        self.position = position
        self.home = home
        self.top_z = top_z
        self.log = log
        self.obstacles = obstacles
        self.grid: ExplorationGrid | None = None
        self.own: list[Candidate] = []
        self.target: Target | None = None
        self.flight: Flight | None = None  # set when the mission starts
        # viewpoints this drone looked from, not the frontier points it looked at: exhaustion compares viewpoints,
        # and a point can lie farther than visited_radius_m from its viewpoint (it was then never exhausted)
        self.visited: list[Vec3] = []
        # viewpoints this drone could not plan a path to, and when: its map may shut a door the others see open
        self.unreachable: list[tuple[Vec3, float]] = []
        self.done = False
        self.done_reason = ""
        self.wake = asyncio.Event()  # run a decision now
        self.retarget = asyncio.Event()  # the flight must drop its path
        self._decisions: asyncio.Task[None] | None = None
        self.reports: dict[int, tuple[float, FrontierReport]] = {}
        self.last_assignment: dict[int, tuple[float, TargetAssignment]] = {}  # leader -> latest
        self.following: tuple[int | None, float] = (None, 0.0)  # the leader we report to, since when
        self.assigned_current: dict[int, Vec3] = {}  # as leader: each member's current target
        self.arrived = False
        self.round = 0
        self.report_seq = 0
        self.empty_rounds = 0
        self.loops = 0
        self.targets_assigned = 0
        self.targets_self_selected = 0
        self.started = time.monotonic()
        self.decision_ms: list[float] = []

    # -- bus ---------------------------------------------------------------------------------------------

    def start(self) -> None:
        if self.strategy in ("coordinated", "frontier-only"):
            self.bus.subscribe(self.bus.keys.all_frontiers, FrontierReport, self._on_report)
            self.bus.subscribe(self.bus.keys.all_targets, TargetAssignment, self._on_assignment)

    def _on_report(self, key: str, report: FrontierReport) -> None:
        if self.bus.keys.agent_id_of(key) != report.id or report.id == self.id:
            return
        self.reports[report.id] = (time.monotonic(), report)
        if report.arrived and self.peers.leader == self.id:
            self.wake.set()

    def _on_assignment(self, key: str, assignment: TargetAssignment) -> None:
        if self.bus.keys.agent_id_of(key) != assignment.leader or assignment.leader == self.id:
            return
        self.last_assignment[assignment.leader] = (time.monotonic(), assignment)
        if assignment.leader != self.peers.leader or self.done:
            return  # not (or no longer) our leader: ignore
        if assignment.done:
            self._finish(f"leader {assignment.leader} declared the cluster done")
            return
        mine = assignment.target_of(self.id)
        if mine is not None:
            self._set_target(Target(mine[0], mine[1], "leader"))

    # -- decisions ---------------------------------------------------------------------------------------

    async def decide_forever(self) -> None:
        """The decision loop: at once (a drone that has just taken off needs a target, not a loop's wait), then
        every loop_s, or at once when woken; keeps announcing `done` once done."""
        while True:
            await self.decide()
            await wait_event(self.wake, self.settings.loop_s)
            self.wake.clear()

    async def decide(self) -> None:
        if self.done and self.peers.leader != self.id:
            return
        here = self.position()
        home = self.home()
        if home is None:
            return
        started = time.perf_counter()
        self.grid, frontiers = await self.mapping.explore_view(home[2], self.top_z, here, self.obstacles())
        self.loops += 1
        self.own = self._candidates(frontiers)
        self._check_path()
        if self.strategy == "uncoordinated":
            self._choose_own()
        elif self.peers.leader == self.id:
            self._lead(here)
        else:
            self._explore(here)
        self.arrived = False
        self.decision_ms.append((time.perf_counter() - started) * 1000)
        if self.loops % STATUS_EVERY_LOOPS == 0:  # a trace of quiet stretches (no new target for minutes)
            self.log("explore_status", loops=self.loops, candidates=len(self.own), leader=self.peers.leader,
                     target=_r(self.target.viewpoint) if self.target else None, path=len(self._path_ahead()))

    def _candidates(self, frontiers: list[Frontier]) -> list[Candidate]:
        own = [Candidate(f.viewpoint, f.point, f.gain, self.id) for f in frontiers[:MAX_CANDIDATES]]
        if not self.visited:
            return own
        return merge_candidates(
            own, {}, gain_now=None, min_gain=0.0, exhausted=self.visited,
            exhausted_radius=self.settings.visited_radius_m, merge_radius=0.0,
        )

    def _check_path(self) -> None:
        """Replan when the map now shows the path blocked; drop a target that is no longer a frontier."""
        if self.grid is None or self.target is None:
            return
        here = self.position()
        ahead = self._path_ahead()  # not the waypoints already passed: a line back to them can cross a wall
        # from a cell that is not safe, the path's first leg leads to a safe one: only the rest can be blocked
        legs = [here, *ahead] if self.grid.planning_grid.is_free(here) else ahead
        if ahead and not path_is_free(self.grid.planning_grid, legs):
            self.log("path_blocked", target=_r(self.target.viewpoint))
            self.retarget.set()
        if not self.grid.is_frontier_near(self.target.point, self.settings.cluster_size_m):
            self.log("target_explored", target=_r(self.target.viewpoint))
            self.target = None
            self.arrived = True  # ask for a new one now
            self.retarget.set()

    def _path_ahead(self) -> list[Vec3]:
        return self.flight.path_ahead if self.flight is not None else []

    def _choose_own(self) -> None:
        """Eq. 3.3 on this drone's own candidates (uncoordinated, or an explorer whose leader went quiet)."""
        if self.done:
            return
        choice = assign_targets(
            self.own, {self.id: self.position()}, lam=self.settings.utility_lambda, sigma=self.settings.sigma_m,
            current=self._current(), current_bonus=self.settings.current_target_bonus, keep_radius=KEEP_RADIUS_M,
            unreachable={self.id: self._recently_unreachable()}, unreachable_radius=self.settings.visited_radius_m,
        ).get(self.id)
        if choice is None:
            if not self.own:  # candidates it cannot reach now come back after UNREACHABLE_RETRY_S
                self._count_empty("no frontier left in this drone's map")
            return
        self.empty_rounds = 0
        self._set_target(Target(choice.viewpoint, choice.point, "self"))

    def _explore(self, here: Vec3) -> None:
        self.report_seq += 1
        report = FrontierReport(
            id=self.id, epoch=self.epoch, seq=self.report_seq, position=here,
            viewpoints=as_points([c.viewpoint for c in self.own]), points=as_points([c.point for c in self.own]),
            gains=np.asarray([c.gain for c in self.own], dtype=np.float32),
            visited=as_points(self.visited[-MAX_VISITED:]),
            unreachable=as_points(self._recently_unreachable()[-MAX_VISITED:]), arrived=self.arrived,
        )
        self.bus.publish(self.bus.keys.frontiers(self.id), report, reliable=True)
        leader, now = self.peers.leader, time.monotonic()
        if self.following[0] != leader:
            # tau runs from our first report to this leader: before it, the leader had nothing to assign us
            self.following = (leader, now)
        heard = self.last_assignment.get(leader)
        waited = now - max(self.following[1], heard[0] if heard else 0.0)
        if waited > self.settings.explorer_timeout_s and (self.target is None or self.target.source == "self"):
            self._choose_own()

    def _lead(self, here: Vec3) -> None:
        assert self.grid is not None
        members = self.peers.cluster
        if self.done:
            self._publish_done(members)  # again every loop: a lost message or a late member still hears it
            return
        fresh_after = time.monotonic() - REPORT_FRESH_LOOPS * self.settings.loop_s
        reports = {k: r for k, (t, r) in self.reports.items() if k in members and t >= fresh_after}
        received = {k: _report_candidates(r) for k, r in reports.items()}
        exhausted = [*self.visited, *(tuple(map(float, v)) for r in reports.values() for v in r.visited)]
        if self.strategy == "frontier-only":
            pooled = remove_overlapped({self.id: self.own, **received})
            merged = merge_candidates(
                pooled, {}, gain_now=None, min_gain=0.0, exhausted=exhausted,
                exhausted_radius=self.settings.visited_radius_m, merge_radius=self.settings.cluster_size_m,
            )
        else:
            merged = merge_candidates(
                self.own, received, gain_now=self.grid.gain_at, min_gain=self.settings.min_gain_m3,
                exhausted=exhausted, exhausted_radius=self.settings.visited_radius_m,
                merge_radius=self.settings.cluster_size_m,
            )
        self.round += 1
        if not merged:
            self._count_empty(f"leader {self.id}: no candidate left in cluster {members}")
            if self.done:
                self._publish_done(members)
            return
        self.empty_rounds = 0
        positions = {self.id: here}
        for k in members:
            if k != self.id and k in self.peers.peers:
                positions[k] = self.peers.peers[k].position
        choice = assign_targets(
            merged, positions, lam=self.settings.utility_lambda, sigma=self.settings.sigma_m,
            current={k: v for k, v in self.assigned_current.items() if k in positions},
            current_bonus=self.settings.current_target_bonus, own_bonus=self.settings.own_frontier_bonus,
            keep_radius=KEEP_RADIUS_M, unreachable_radius=self.settings.visited_radius_m,
            unreachable={self.id: self._recently_unreachable(), **{k: r.unreachable for k, r in reports.items()}},
        )
        assigned = {k: c for k, c in choice.items() if c is not None}
        self.assigned_current = {k: c.viewpoint for k, c in assigned.items()}
        drones = sorted(assigned)
        self.bus.publish(
            self.bus.keys.targets(self.id),
            TargetAssignment(
                leader=self.id, epoch=self.epoch, round=self.round, members=members, drones=drones,
                viewpoints=as_points([assigned[k].viewpoint for k in drones]),
                points=as_points([assigned[k].point for k in drones]),
            ),
            reliable=True,
        )
        mine = assigned.get(self.id)
        if mine is not None:
            self._set_target(Target(mine.viewpoint, mine.point, "leader"))

    def _count_empty(self, reason: str) -> None:
        self.empty_rounds += 1
        if self.empty_rounds >= EMPTY_ROUNDS_FOR_DONE and self.target is None:
            self._finish(reason)

    def _publish_done(self, members: list[int]) -> None:
        self.bus.publish(
            self.bus.keys.targets(self.id),
            TargetAssignment(leader=self.id, epoch=self.epoch, round=self.round, members=members, done=True),
            reliable=True,
        )

    def _current(self) -> dict[int, Vec3]:
        return {self.id: self.target.viewpoint} if self.target is not None else {}

    def _set_target(self, target: Target) -> bool:
        """Take a new target; False when it is the current one (kept without interrupting the flight)."""
        current = self.target
        if current is not None and _distance(current.viewpoint, target.viewpoint) < KEEP_RADIUS_M:
            # Update the same object: `fly` knows its target by identity, and a new object at every loop meant it
            # never counted as reached (no dwell, never done, the same spot assigned again: a silent livelock).
            current.point, current.source = target.point, target.source
            return False
        self.target = target
        if target.source == "self":
            self.targets_self_selected += 1
        else:
            self.targets_assigned += 1
        self.log("target", viewpoint=_r(target.viewpoint), point=_r(target.point), source=target.source,
                 replaces=_r(current.viewpoint) if current is not None else None)
        self.retarget.set()
        return True

    def _finish(self, reason: str) -> None:
        if not self.done:
            self.done, self.done_reason = True, reason
            self.log("exploration_done", reason=reason, loops=self.loops)
        self.target = None
        self.retarget.set()

    # -- flight ------------------------------------------------------------------------------------------

    async def fly(self, flight: Flight, stop: asyncio.Event) -> None:
        """The mission: go to targets as they come until the exploration is done, then return home. The decision
        loop starts here, once airborne, and runs until `close` (a done leader keeps saying so)."""
        self.flight = flight
        self._decisions = asyncio.create_task(self.decide_forever())
        while not self.done:
            target = self.target
            if target is None or self.grid is None:
                # A new target ends the wait: the turn is only to map while there is nothing better to do. What
                # set `retarget` before is done with (a target dropped as explored sets it too): left set, every
                # wait would end at once and this loop would spin without ever yielding.
                self.retarget.clear()
                await flight.face(self._look_around(flight), WAIT_FOR_TARGET_S, stop, interrupt=self.retarget)
                continue
            self.retarget.clear()
            path = await self._plan(target.viewpoint)
            if path is None:
                path = await self._plan_to_another_viewpoint(target)
            if path is None:
                self._cannot_reach(target)
                continue
            reached = await flight.fly_path(path, stop, interrupt=self.retarget)
            if reached and self.target is target:
                # The next target is decided while this one is looked at (the look is not cut short by it): an
                # explorer's next target takes two decisions (its report, its leader's assignment), and waiting
                # for them after the look left every drone hovering for most of a second at every target.
                self.log("target_reached", viewpoint=_r(target.viewpoint))
                self._looked_at(target)
                await flight.face(target.point, self.settings.dwell_s, stop)
                if self.target is target:
                    self.target = None
        home = self.home()
        if self.settings.return_home and home is not None:
            await self._return(flight, stop, home)

    def _look_around(self, flight: Flight) -> Vec3:
        """A point IDLE_TURN_DEG to the left of where we look: waiting for a target, the drone turns and maps."""
        here = self.position()
        yaw = math.radians(flight.ap.telemetry.yaw_deg + IDLE_TURN_DEG)
        return here[0] + math.cos(yaw), here[1] + math.sin(yaw), here[2]

    async def close(self) -> None:
        if self._decisions is not None:
            self._decisions.cancel()
            await asyncio.gather(self._decisions, return_exceptions=True)

    async def _plan(self, goal: Vec3) -> list[Vec3] | None:
        """The waypoints to fly from here to `goal`, or None. When the drone is in a cell that is not safe (it
        stepped aside, or the map grew round it), the path starts at the nearest safe cell and so does the
        flight: straight from the drone to the second waypoint was never checked (a drone that had stepped up
        flew through a doorway with its top in the lintel)."""
        grid = self.grid
        assert grid is not None
        here = self.position()
        try:
            path = await asyncio.to_thread(
                plan_path, grid.planning_grid, here, goal, max_expansions=PLAN_EXPANSIONS
            )
        except NoPathError as exc:
            self.log("no_path", goal=_r(goal), reason=str(exc))
            return None
        self.log("path", waypoints=[_r(p) for p in path])
        return path[1:] if path[0] == here else path

    async def _plan_to_another_viewpoint(self, target: Target) -> list[Vec3] | None:
        """A path to another place this drone's map lets it look at the target's point from, or None. A
        viewpoint from another drone's report can be blocked in this drone's map (patches on their way, or the
        reporter's own position counted as free in its map); the target is still the same one."""
        assert self.grid is not None
        seen_from = self.grid.viewpoint_for(target.point, self.position())
        if seen_from is None or _distance(seen_from, target.viewpoint) < 1e-6:
            return None
        self.log("viewpoint_moved", target=_r(target.viewpoint), to=_r(seen_from))
        return await self._plan(seen_from)

    def _cannot_reach(self, target: Target) -> None:
        """No path to the target's viewpoint in this drone's map: it is not given to this drone again for
        UNREACHABLE_RETRY_S (the others may reach it, and the map may open up), and after UNREACHABLE_GIVE_UP
        failures it is done with, as if visited."""
        now = time.monotonic()
        self.unreachable.append((target.viewpoint, now))
        failures = sum(_distance(v, target.viewpoint) <= self.settings.visited_radius_m for v, _ in self.unreachable)
        if failures >= UNREACHABLE_GIVE_UP:
            self.log("unreachable_given_up", viewpoint=_r(target.viewpoint), failures=failures)
            self._done_with(target)
            return
        if self.target is target:
            self.target = None
        self.arrived = True
        self.wake.set()

    def _recently_unreachable(self) -> list[Vec3]:
        since = time.monotonic() - UNREACHABLE_RETRY_S
        return [v for v, t in self.unreachable if t >= since]

    def _done_with(self, target: Target) -> None:
        """A target given up as unreachable: nobody is sent there again, and the cluster assigns again now."""
        self._looked_at(target)
        if self.target is target:
            self.target = None

    def _looked_at(self, target: Target) -> None:
        """A target reached (its look is starting) or given up: it counts as visited, and the cluster assigns
        again now."""
        self.visited.append(target.viewpoint)
        self.arrived = True
        self.wake.set()

    async def _return(self, flight: Flight, stop: asyncio.Event, home: Vec3) -> None:
        above = (home[0], home[1], home[2] + self.config.agent.altitude_m)
        reason = "kept giving way"
        for attempt in range(1, RETURN_ATTEMPTS + 1):
            path = await self._plan(above) if self.grid is not None else None
            if path is None:
                reason = "no path home"
                break
            if await flight.fly_path(path, stop):
                return
            self.log("return_replan", attempt=attempt)  # gave way too long: plan again from here
        self.log("land_in_place", reason=reason)

    def summary(self) -> dict[str, Any]:
        ms = sorted(self.decision_ms)
        return {
            "strategy": self.strategy,
            "targets_assigned": self.targets_assigned,
            "targets_self_selected": self.targets_self_selected,
            "exploration_loops": self.loops,
            "exploration_done": self.done,
            "exploration_done_reason": self.done_reason,
            "targets_visited": len(self.visited),
            "decision_ms_p50": round(ms[len(ms) // 2], 1) if ms else None,
            "decision_ms_max": round(ms[-1], 1) if ms else None,
        }


def _report_candidates(report: FrontierReport) -> list[Candidate]:
    return [
        Candidate(_vec(v), _vec(p), float(g), report.id)
        for v, p, g in zip(report.viewpoints, report.points, report.gains)
    ]


def _vec(row: np.ndarray) -> Vec3:
    return float(row[0]), float(row[1]), float(row[2])


def _distance(a: Vec3, b: Vec3) -> float:
    return float(np.linalg.norm(np.subtract(a, b)))


def _r(p: Vec3) -> list[float]:
    return [round(float(v), 2) for v in p]
