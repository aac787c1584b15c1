"""One drone's exploration: the asyncio and bus glue round `swarm.roles.protocol.ExplorationCore`.

Every `explore.loop_s` (r), and at once when a drone of the cluster reaches its target, the agent computes its
frontiers from its fused map (`MappingTask.explore_view`; a decision within `explore.view_reuse_s` of the last
view decides on that one, since a leader is woken by every arrival) and hands them to the core with the drone's
situation; the core decides (explorer reports, leader assignments, tau, termination: see its docstring) and this module
publishes what it says and interrupts the flight when the target changes. Strategies: docs/architecture.md,
"Exploration".

The flight side (`fly`) plans a path on the latest grid to the current target's viewpoint, flies it (the
decision loop interrupts it when the target changes or the path becomes blocked), turns to the frontier point
for `dwell_s`, and reports that it arrived. A drone whose map shuts it in where it is (a pocket) gets out
before it calls a target unreachable, and instead of waiting for a target that cannot come. When the mission is
done it returns above its take-off point; so it does, planned the same way (`fly_home`), when a low battery ends
its flight early.
"""

from __future__ import annotations

import asyncio
import functools
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from swarm.agent.events import log_if_failed
from swarm.agent.flight import PASS_CLEARANCE_M, SILENT_CLEAR_M, Flight, distance_to_segment
from swarm.agent.mapping import MappingTask
from swarm.aio import wait_event
from swarm.bus.bridge import AsyncBus
from swarm.config import SwarmConfig, Vec3
from swarm.explore.frontiers import ExplorationGrid, Frontier
from swarm.explore.planner import NoPathError, path_is_free, plan_path, plan_path_around
from swarm.roles.membership import PeerTable
from swarm.roles.messages import FrontierReport, TargetAssignment
from swarm.roles.protocol import Effects, ExplorationCore, ReportLimits, Situation, Target
from swarm.stages import NO_CLOCK, StageClock

PLAN_EXPANSIONS = 150_000
PARKED_PEER_S = 10.0  # a peer this drone gave a segment up for is planned round for this long
STATUS_EVERY_LOOPS = 10
RETURN_ATTEMPTS = 3  # a drone that had to give way too long on its way home plans again
WAIT_FOR_TARGET_S = 0.5
IDLE_TURN_DEG = 45.0
IDLE_ROUNDS = 2  # decisions for an idle drone, after idle_home_s, before it heads home (the first may predate it)
IDLE_WITHOUT_ROUNDS = 5.0  # ... or this many times idle_home_s with no decision at all (rounds that never come)
MOVED_ON_M = 0.1  # a drone this far from where its path was planned checks the straight way on from where it is

__all__ = ["Exploration", "Target"]


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
        clock: StageClock = NO_CLOCK,
        patches_to_come: Callable[[list[int]], int] = lambda members: 0,
    ) -> None:
        self.config = config
        self.clock = clock  # stage costs (swarm.stages): decision, assignment, planning
        self.patches_to_come = patches_to_come  # members -> patches they hold that our map lacks (the sync's)
        self.settings = config.explore
        self.strategy = config.explore.strategy
        self.id = config.agent.id
        self.bus = bus
        self.peers = peers
        self.mapping = mapping
        self.position = position
        self.home = home
        self.top_z = top_z
        self.log = log
        self.obstacles = obstacles
        self.core = ExplorationCore(
            config.explore, self.id, epoch, time.monotonic(), limits=ReportLimits.from_config(config)
        )
        self.grid: ExplorationGrid | None = None
        self.flight: Flight | None = None  # set when the mission starts
        self.wake = asyncio.Event()  # run a decision now
        self.returning = False  # a low battery sent the drone home early (fly_home): it decides no more
        self.retarget = asyncio.Event()  # the flight must drop its path
        self._decisions: asyncio.Task[None] | None = None
        self.decision_ms: list[float] = []  # decisions on a new view (`view_reuse_s`)
        self._view: tuple[float, list[Frontier]] | None = None  # when the last view was taken, its frontiers
        self.views_reused = 0  # decisions made on the last view (taken under `view_reuse_s` before)
        # The core decides in a worker thread, not on the event loop (a leader's round took up to 2.9 s on a
        # loaded machine, and its peers, hearing no heartbeat for 3 s, took it for lost); not in the decision
        # thread either, which is nicer than the process: what it runs holds the GIL in long C calls (Dijkstra),
        # and the event loop would wait for it while the scheduler keeps the nicer thread off the cores. The core
        # is not thread-safe: while it decides, inputs from the bus wait in `_deferred`, and the flight waits
        # (`_core_ready`) before it tells the core anything.
        self._deciding = False
        self._core_free = asyncio.Event()
        self._core_free.set()
        self._deferred: list[Callable[[], Effects]] = []

    @property
    def target(self) -> Target | None:
        return self.core.target

    @target.setter
    def target(self, target: Target | None) -> None:
        self.core.target = target

    @property
    def done(self) -> bool:
        return self.core.done

    @property
    def visited(self) -> list[Vec3]:
        return self.core.visited

    # -- bus ---------------------------------------------------------------------------------------------

    def start(self) -> None:
        if self.strategy in ("coordinated", "frontier-only"):
            self.bus.subscribe(self.bus.keys.all_frontiers, FrontierReport, self._on_report)
            self.bus.subscribe(self.bus.keys.all_targets, TargetAssignment, self._on_assignment)

    def _on_report(self, key: str, report: FrontierReport) -> None:
        sender = self.bus.keys.agent_id_of(key)
        self._to_core(lambda: self.core.on_report(time.monotonic(), sender, report, self.peers.leader))

    def _on_assignment(self, key: str, assignment: TargetAssignment) -> None:
        sender = self.bus.keys.agent_id_of(key)
        self._to_core(lambda: self.core.on_assignment(time.monotonic(), sender, assignment, self.peers.leader))

    def _to_core(self, call: Callable[[], Effects]) -> None:
        """Give the core an input now, or, while it decides in its worker thread, as soon as it has decided (in
        order of arrival; the time and leader it is given are those of then)."""
        if self._deciding:
            self._deferred.append(call)
        else:
            self._apply(call())

    async def _core_ready(self) -> None:
        """Wait until the core is not deciding (the flight's inputs to it, on the event loop, come after)."""
        while self._deciding:
            await self._core_free.wait()

    def _apply(self, effects: Effects) -> None:
        """Carry out what the core decided: log, publish (reliable: a lost one is replaced next loop), wake."""
        for event, fields in effects.events:
            self.log(event, **fields)
        for message in effects.publish:
            key = (
                self.bus.keys.frontiers(self.id)
                if isinstance(message, FrontierReport)
                else self.bus.keys.targets(self.id)
            )
            self.bus.publish(key, message, reliable=True)
        if effects.retarget:
            self.retarget.set()
        if effects.wake:
            self.wake.set()

    # -- decisions ---------------------------------------------------------------------------------------

    async def decide_forever(self) -> None:
        """The decision loop: at once (a drone that has just taken off needs a target, not a loop's wait), then
        every loop_s, or at once when woken; keeps announcing `done` once done."""
        while True:
            await self.decide()
            await wait_event(self.wake, self.settings.loop_s)
            self.wake.clear()

    async def decide(self) -> None:
        if self.returning or (self.core.done and self.peers.leader != self.id):
            return  # a returning drone is out of its cluster (phase returning): it neither reports nor leads
        here = self.position()
        home = self.home()
        if home is None:
            return
        started = time.perf_counter()
        last = self._view
        reused = last is not None and time.monotonic() - last[0] < self.settings.view_reuse_s
        if last is not None and reused:
            frontiers = last[1]
            self.views_reused += 1
        else:
            self.grid, frontiers = await self.mapping.explore_view(home[2], self.top_z, here, self.obstacles())
            self._view = (time.monotonic(), frontiers)
        assert self.grid is not None  # set with the view
        if self._check_path() and self.flight is not None:
            await self.flight.brake()
        members = self.peers.cluster
        situation = Situation(
            here=here,
            leader=self.peers.leader,
            cluster=members,
            positions={k: self.peers.peers[k].position for k in members if k != self.id and k in self.peers.peers},
            frontiers=frontiers,
            map=self.grid,
            in_pocket=self.grid.in_pocket(here),
            tracks={k: self.peers.peers[k].track_array() for k in members if k in self.peers.peers},
            patches_to_come=self.patches_to_come([k for k in members if k != self.id]),
            home=self._above_home() if self.settings.return_home else None,
        )
        self._deciding = True
        self._core_free.clear()
        try:
            effects = await asyncio.to_thread(self._core_decides, time.monotonic(), situation)
        finally:
            self._deciding = False
            self._core_free.set()
        if self.returning:
            self.target = None  # a low battery sent it home while the core decided: it takes no target
        self._apply(effects)
        deferred, self._deferred = self._deferred, []
        for call in deferred:
            self._apply(call())
        elapsed = time.perf_counter() - started
        if reused:
            self.clock.record("decision_on_last_view", elapsed)
        else:
            self.decision_ms.append(elapsed * 1000)
            self.clock.record("decision", elapsed)
        if self.core.loops % STATUS_EVERY_LOOPS == 0:  # a trace of quiet stretches (no new target for minutes)
            self.log(
                "explore_status",
                loops=self.core.loops,
                candidates=len(self.core.own),
                leader=self.peers.leader,
                target=_r(self.target.viewpoint) if self.target else None,
                path=len(self._path_ahead()),
                in_pocket=situation.in_pocket,
            )

    def _core_decides(self, now: float, situation: Situation) -> Effects:
        with self.clock.measure("assignment"):  # the core: reports merged, targets assigned, termination
            return self.core.decide(now, situation)

    def _check_path(self) -> bool:
        """Replan when the map now shows the path ahead blocked; True when the straight way from the drone to
        its carrot, the setpoint it is flying to right now, is blocked too (the caller brakes)."""
        if self.grid is None or self.target is None:
            return False
        here = self.position()
        ahead = self._path_ahead()  # not the waypoints already passed: a line back to them can cross a wall
        # The drone flies to the carrot, then along the path from there: round a corner it may be well inside
        # the path, and the straight line from it to the next waypoint is not a way it flies.
        carrot = self.flight.setpoint if self.flight is not None and ahead else None
        way = [carrot, *ahead] if carrot is not None else ahead
        # from a cell that is not safe, the path's first leg leads to a safe one: only the rest can be blocked
        from_here = self.grid.planning_grid.is_free(here)
        legs = [here, *way] if from_here else way
        if not ahead or path_is_free(self.grid.planning_grid, legs):
            return False
        brake = from_here and carrot is not None and not path_is_free(self.grid.planning_grid, [here, carrot])
        self.log("path_blocked", target=_r(self.target.viewpoint), brake=brake)
        self.retarget.set()
        return brake

    def _path_ahead(self) -> list[Vec3]:
        return self.flight.path_ahead if self.flight is not None else []

    def _finish(self, reason: str) -> None:
        effects = Effects()
        self.core.finish(effects, reason)
        self._apply(effects)

    # -- flight ------------------------------------------------------------------------------------------

    async def fly(self, flight: Flight, stop: asyncio.Event) -> None:
        """The mission: go to targets as they come until the exploration is done, then return home. The decision
        loop starts here, once airborne, and runs until `close` (a done leader keeps saying so)."""
        self.flight = flight
        self._decisions = log_if_failed(asyncio.create_task(self.decide_forever(), name="decisions"), self.log)
        idle_since: float | None = None  # when the drone was last left without a target
        while not self.done:
            target = self.target
            if target is None or self.grid is None:
                # A new target ends the wait: the turn is only to map while there is nothing better to do. What
                # set `retarget` before is done with (a target dropped as explored sets it too): left set, every
                # wait would end at once and this loop would spin without ever yielding.
                self.retarget.clear()
                idle_since = time.monotonic() if idle_since is None else idle_since
                # From a pocket no frontier worth a target may be in sight (the take-off spot, with the unseen
                # cone above it, is one): waiting there would wait for ever.
                if self.grid is not None and await self._out_of_pocket(flight, stop):
                    continue
                await self._core_ready()  # its rounds are counted by the core, which may be deciding
                idle = should_head_home(
                    time.monotonic() - idle_since,
                    self._left_out_since(idle_since),
                    self.core.rounds_since(idle_since),
                    self.settings.idle_home_s,
                )
                if not (idle and await self._head_home(flight, stop)):
                    await flight.face(self._look_around(flight), WAIT_FOR_TARGET_S, stop, interrupt=self.retarget)
                continue
            idle_since = None
            self.retarget.clear()
            parked = self._parked_in_the_way(flight)
            path = None
            if parked is not None and math.dist(parked, target.viewpoint) < PASS_CLEARANCE_M:
                # the peer this drone held for waits at the viewpoint itself (a refuge it stepped aside to): going
                # round it cannot get there, and both would hold for each other until one gave the target up
                path = await self._plan_to_another_viewpoint(target, keep_off=parked)
            if path is None:
                path = await self._plan(target.viewpoint, around=parked)
            if path is None:
                path = await self._plan_to_another_viewpoint(target, keep_off=parked)
            if path is None:
                if not await self._out_of_pocket(flight, stop):
                    await self._core_ready()
                    self._apply(self.core.cannot_reach(time.monotonic(), target, self.grid))
                continue
            reached = await flight.fly_path(path, stop, interrupt=self.retarget)
            if reached and self.target is target:
                # The next target is decided while this one is looked at (the look is not cut short by it): an
                # explorer's next target takes two decisions (its report, its leader's assignment), and waiting
                # for them after the look left every drone hovering for most of a second at every target.
                self.log("target_reached", viewpoint=_r(target.viewpoint))
                # idle from here, as far as decisions go: the one this arrival wakes counts the target looked at,
                # and when it finds nothing for this drone, the drone heads home after the look
                idle_since = time.monotonic()
                self._to_core(functools.partial(self.core.looked_at, target))  # the look starts now, deciding or not
                await flight.face(target.point, self.settings.dwell_s, stop)
                await self._core_ready()  # before the loop reads the next target: the look is counted first
                self.core.look_finished(target)
        home = self.home()
        if self.settings.return_home and home is not None:
            await self._return(flight, stop, home)

    def _left_out_since(self, idle_since: float) -> bool:
        """A decision since the drone became idle found nothing for it: it is not waiting for its next target."""
        left_out = self.core.left_out_at
        return left_out is not None and left_out >= idle_since

    def _look_around(self, flight: Flight) -> Vec3:
        """A point IDLE_TURN_DEG to the left of where we look: waiting for a target, the drone turns and maps."""
        here = self.position()
        yaw = math.radians(flight.ap.telemetry.yaw_deg + IDLE_TURN_DEG)
        return here[0] + math.cos(yaw), here[1] + math.sin(yaw), here[2]

    async def close(self) -> None:
        if self._decisions is not None:
            self._decisions.cancel()
            await asyncio.gather(self._decisions, return_exceptions=True)

    def _parked_in_the_way(self, flight: Flight) -> Vec3 | None:
        """Where the peer sits that made this drone give its last segment up (it had the right of way, and the
        peer would not move off), when that was in the last PARKED_PEER_S."""
        if flight.blocked_by is None:
            return None
        peer, since = flight.blocked_by
        return peer.position if time.monotonic() - since <= PARKED_PEER_S else None

    async def _plan(self, goal: Vec3, around: Vec3 | None = None, start: Vec3 | None = None) -> list[Vec3] | None:
        """The waypoints to fly from here to `goal`, or None. When the drone is in a cell that is not safe (it
        stepped aside, or the map grew round it), the path starts at the nearest safe cell and so does the
        flight: straight from the drone to the second waypoint was never checked (a drone that had stepped up
        flew through a doorway with its top in the lintel).

        `around`: a peer parked in the way. The path keeps PASS_CLEARANCE_M from it when the map allows, so the
        drone does not hold for it again; otherwise it is the plain path, unless that passes within
        SILENT_CLEAR_M of the peer: then there is no path for now (the drone would only hold for it again,
        and the peer waits for this drone to pass). Replanning the same path past a drone that waits for this
        one to pass held both for minutes (a refuge beside a doorway, 0.26 m off the way through it; office, 3
        drones: a refuge in a doorway, no refuge clear of the way there, 5 minutes until the mission timed out).

        `start`: plan from there instead (a point the drone will fly to first). Where the map's safe cells do not
        join the start and the goal (`ExplorationGrid.connected`), there is no path, and no search."""
        grid = self.grid
        assert grid is not None
        here = self.position() if start is None else start
        if not grid.connected(here, goal):
            # The map's safe space does not join them: A* would learn that only by searching all of one side,
            # 100,000 cells and seconds of hovering in a large building.
            self.log("no_path", goal=_r(goal), reason="not joined to the start by this map's safe cells")
            return None
        if around is not None:
            try:
                path = await asyncio.to_thread(
                    self._timed_plan,
                    lambda: plan_path_around(
                        grid.planning_grid,
                        here,
                        goal,
                        around,
                        PASS_CLEARANCE_M,
                        max_expansions=PLAN_EXPANSIONS,
                        guide=lambda: grid.travel_graph,
                    ),
                )
            except NoPathError:
                pass
            else:
                self.log("path", waypoints=[_r(p) for p in path], around=_r(around))
                return self._from_where_it_is(path, here, start is None)
        try:
            path = await asyncio.to_thread(
                self._timed_plan,
                lambda: plan_path(
                    grid.planning_grid, here, goal, max_expansions=PLAN_EXPANSIONS, guide=lambda: grid.travel_graph
                ),
            )
        except NoPathError as exc:
            self.log("no_path", goal=_r(goal), reason=str(exc))
            return None
        if around is not None and path_clearance([here, *path], around) < SILENT_CLEAR_M:
            self.log("no_path", goal=_r(goal), reason=f"the only way passes the drone waiting at {_r(around)}")
            return None
        self.log("path", waypoints=[_r(p) for p in path])
        return self._from_where_it_is(path, here, start is None)

    def _from_where_it_is(self, path: list[Vec3], planned_from: Vec3, from_the_drone: bool = True) -> list[Vec3]:
        """The waypoints of `path` (planned from `planned_from`) to fly from where the drone is now. A plan takes
        up to seconds, and meanwhile the drone flies on to its last carrot: from there the straight way to the
        path's first waypoint was never checked, so where the map does not show it clear, the flight goes back
        to where the path starts first (a drone 1.3 m on from there turned straight into a wall's end)."""
        ahead = path[1:] if path[0] == planned_from else path
        if not ahead or not from_the_drone:
            return ahead
        now = self.position()
        assert self.grid is not None
        if math.dist(now, planned_from) > MOVED_ON_M and not self.grid.planning_grid.segment_is_free(now, ahead[0]):
            self.log("path_from_start", position=_r(now), start=_r(planned_from))
            return [planned_from, *ahead]
        return ahead

    def _timed_plan(self, plan: Callable[[], list[Vec3]]) -> list[Vec3]:
        """Run `plan` (in a worker thread: the guide, the grid's travel graph, is built on first use there, not
        on the event loop)."""
        with self.clock.measure("planning"):  # a plan that fails (NoPathError) costs as much and counts
            return plan()

    async def _plan_to_another_viewpoint(self, target: Target, keep_off: Vec3 | None = None) -> list[Vec3] | None:
        """A path to another place this drone's map lets it look at the target's point from, or None. A
        viewpoint from another drone's report can be blocked in this drone's map (patches on their way, or the
        reporter's own position counted as free in its map); the target is still the same one. `keep_off`: a
        peer parked at the viewpoint; the other place keeps PASS_CLEARANCE_M from it, and so does the path."""
        assert self.grid is not None
        seen_from = self.grid.viewpoint_for(target.point, self.position(), keep_off, PASS_CLEARANCE_M)
        if seen_from is None or math.dist(seen_from, target.viewpoint) < 1e-6:
            return None
        self.log("viewpoint_moved", target=_r(target.viewpoint), to=_r(seen_from))
        return await self._plan(seen_from, around=keep_off)

    async def _out_of_pocket(self, flight: Flight, stop: asyncio.Event) -> bool:
        """When the drone's map shuts it in where it is (a pocket: every plan fails after a few cells), fly to
        the nearest open safe cell, or turn to map more when there is none, and say so: a failed plan from a
        pocket says nothing about the target. False when the drone is not in a pocket."""
        grid, here = self.grid, self.position()
        if grid is None or not grid.in_pocket(here):
            return False
        out = grid.escape(here)
        self.log("in_pocket", position=_r(here), escape=_r(out) if out is not None else None)
        if out is None:
            await flight.face(self._look_around(flight), WAIT_FOR_TARGET_S, stop, interrupt=self.retarget)
        else:
            await flight.fly_path([out], stop, interrupt=self.retarget)
        self.wake.set()
        return True

    def _above_home(self) -> Vec3 | None:
        home = self.home()
        return None if home is None else (home[0], home[1], home[2] + self.config.agent.altitude_m)

    async def _head_home(self, flight: Flight, stop: asyncio.Event) -> bool:
        """While there is nothing to explore for this drone, fly towards home until a new target (or the end of
        the mission) interrupts: the return is then mostly flown while the others finish. False when there is
        no home to go to or no path (the caller waits in place instead) or the drone is there already."""
        above = self._above_home()
        if not self.settings.return_home or above is None or self.grid is None:
            return False
        if math.dist(self.position(), above) <= self.settings.arrive_tolerance_m:
            return False
        path = await self._plan(above)
        if path is None:
            return False
        self.log("heading_home", idle_s=self.settings.idle_home_s)
        await flight.fly_path(path, stop, interrupt=self.retarget)  # a target, or `done`, sets retarget
        return True

    async def fly_home(self, flight: Flight, stop: asyncio.Event) -> None:
        """The flight's way home when it ends the mission early (a low battery): the targets are left to the others
        (the heartbeat says returning, which takes this drone out of every cluster), and the drone returns above
        its take-off point as at the end of the mission."""
        self.returning = True
        self.target = None
        home = self.home()
        if home is None:
            self.log("land_in_place", reason="no home position")
            return
        await self._return(flight, stop, home)

    async def _return(self, flight: Flight, stop: asyncio.Event, home: Vec3) -> None:
        """Back above home on a path planned on the map; where the map shows none (home's cell looks blocked
        beside a wall, say, or no map yet), back the way the drone came: every leg of that was flown."""
        above = (home[0], home[1], home[2] + self.config.agent.altitude_m)
        for attempt in range(1, RETURN_ATTEMPTS + 1):
            path = await self._plan(above) if self.grid is not None else None
            if path is None:
                break
            if await flight.fly_path(path, stop):
                return
            self.log("return_replan", attempt=attempt)  # gave way too long: plan again from here
        else:
            self.log("land_in_place", reason="kept giving way")
            return
        way_back = await self._back_until_the_map_leads_home(flight.way_back(), above)
        self.log("retrace_home", reason="no path home", waypoints=len(way_back))
        if not await flight.fly_path(way_back, stop):
            self.log("land_in_place", reason="no path home, and kept giving way on the way back")

    async def _back_until_the_map_leads_home(self, way_back: list[Vec3], above: Vec3) -> list[Vec3]:
        """The way the drone came, back to the first of its waypoints from which the map shows a way to `above`
        home, then that way; the whole way back where none does. The map can shut a drone in behind it (a 0.9 m
        door whose jambs, mapped more fully, left no safe cell in it), and retracing a whole mission's
        waypoints took one drone 70 s where the door was 10 s back."""
        grid = self.grid
        if grid is None:
            return way_back
        for k, point in enumerate(way_back[:-1]):
            # in a safe cell itself: the nearest one to a point beside a wall can be on the wall's other side
            if grid.planning_grid.is_free(point) and grid.connected(point, above):
                path = await self._plan(above, start=point)
                return way_back if path is None else [*way_back[: k + 1], *path]
        return way_back

    def summary(self) -> dict[str, Any]:
        ms = sorted(self.decision_ms)
        core = self.core.summary()
        # heartbeat positions farther than a peer could have flown: left out of its track (swarm.roles.membership)
        core["exploration_rejected"] = {**core["exploration_rejected"], "heartbeat_jump": self.peers.track_jumps}
        return {
            **core,
            "decision_ms_p50": round(ms[len(ms) // 2], 1) if ms else None,
            "decision_ms_max": round(ms[-1], 1) if ms else None,
            "decisions_on_last_view": self.views_reused,
        }


def should_head_home(idle_s: float, left_out: bool, rounds: int, idle_home_s: float) -> bool:
    """Whether a drone idle for `idle_s` heads home: a decision since it became idle found nothing for it
    (`left_out`), or it has been idle `idle_home_s` through IDLE_ROUNDS decisions for it (`rounds`: its leader's
    rounds, or its own), or IDLE_WITHOUT_ROUNDS times that with none at all (a leader whose rounds never come).

    Time alone is not enough: on a loaded machine a round can take longer than `idle_home_s` (hall, 5 drones, 2
    cores: 8-10 s at the median), and drones waiting for their next target flew home and back, the leader itself
    four times in two minutes with 60-180 candidates left."""
    if left_out:
        return True
    if idle_s >= IDLE_WITHOUT_ROUNDS * idle_home_s:
        return True
    return idle_s >= idle_home_s and rounds >= IDLE_ROUNDS


def path_clearance(path: list[Vec3], point: Vec3) -> float:
    """How close the polyline `path` comes to `point`."""
    if len(path) < 2:
        return math.dist(path[0], point) if path else math.inf
    p, ends = np.asarray(point, dtype=float), np.asarray(path, dtype=float)
    return min(distance_to_segment(p, a, b) for a, b in zip(ends[:-1], ends[1:]))


def _r(p: Vec3) -> list[float]:
    return [round(float(v), 2) for v in p]
