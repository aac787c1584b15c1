"""`Exploration`'s flight side: when a target counts as visited, how the flight loop waits for the next one,
where paths start and which part of them is checked. The decisions themselves are the core's
(tests/roles/test_protocol.py).

The flight loop knows its target by identity: reaching a target only counts (dwell, "done with it") when the
target it set out for is still the current one.
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from swarm.agent.exploration import IDLE_WITHOUT_ROUNDS, PARKED_PEER_S, Exploration, Target, should_head_home
from swarm.agent.flight import PASS_CLEARANCE_M, Flight, Neighbour
from swarm.bus.phase import Phase
from swarm.config import ExploreSettings, Vec3, load_config
from swarm.explore.frontiers import ExplorationGrid
from swarm.explore.grid import OccupancyGrid
from swarm.explore.planner import path_is_free
from swarm.patches.fused import OCCUPIED
from swarm.roles.membership import PeerTable
from swarm.roles.messages import TargetAssignment, as_points
from swarm.roles.protocol import Effects
from tests.agent.fake_autopilot import FakeAutopilot
from tests.explore.synthetic import room_states, set_states


def _JOINED(a: Vec3, b: Vec3) -> bool:
    """`ExplorationGrid.connected` of a grid whose safe space is one piece."""
    return True


def _give(exploration: Exploration, target: Target) -> None:
    """A target from the leader, as `_on_assignment` hands it over."""
    effects = Effects()
    exploration.core.set_target(effects, target)
    exploration._apply(effects)


def _exploration(events: list[dict[str, Any]], **overrides: Any) -> Exploration:
    config = load_config(overrides={"agent.id": 2, **overrides})
    return Exploration(
        config,
        epoch=1,
        bus=None,
        peers=PeerTable(2),
        mapping=None,  # type: ignore[arg-type]  # unused here
        position=lambda: (0.0, 0.0, 1.5),
        home=lambda: (0.0, 0.0, 0.0),
        top_z=3.0,
        log=lambda event, **fields: events.append({"event": event, **fields}),
    )


async def test_the_decision_loop_decides_at_once_then_every_loop(monkeypatch) -> None:
    """A drone that has just taken off has no target: waiting a loop first cost every mission loop_s (3 s)."""
    exploration = _exploration([], **{"explore.loop_s": 600.0})
    decided = asyncio.Event()

    async def decide() -> None:
        decided.set()

    monkeypatch.setattr(exploration, "decide", decide)
    loop = asyncio.create_task(exploration.decide_forever())
    try:
        await asyncio.wait_for(decided.wait(), timeout=10.0)  # far below the 600 s loop
        decided.clear()
        exploration.wake.set()  # woken (a drone reached its target): decides again without waiting the loop
        await asyncio.wait_for(decided.wait(), timeout=10.0)
    finally:
        loop.cancel()
        await asyncio.gather(loop, return_exceptions=True)


def test_from_a_cell_that_is_not_safe_the_flight_starts_at_the_nearest_safe_cell() -> None:
    blocked = np.zeros((20, 20, 15), dtype=bool)  # 4 x 4 x 3 m at 0.2 m
    blocked[:, :, 9:] = True  # nothing is safe above 1.8 m (under a lintel, say)
    grid = OccupancyGrid(np.zeros(3), 0.2, blocked)
    exploration = _exploration([])
    exploration.grid = SimpleNamespace(planning_grid=grid, connected=_JOINED)  # type: ignore[assignment]
    goal = (3.0, 1.0, 1.5)

    exploration.position = lambda: (1.0, 1.0, 1.5)  # a safe cell: the path's start is the drone itself
    path = asyncio.run(exploration._plan(goal))
    assert path == [goal]

    exploration.position = lambda: (1.0, 1.0, 1.9)  # stepped up out of the safe cells
    path = asyncio.run(exploration._plan(goal))
    assert path is not None and len(path) == 2 and path[-1] == goal
    first = np.array(path[0])  # first down to the nearest safe cell centre (the top safe layer, 1.6-1.8 m)
    assert grid.is_free(first) and first[2] == pytest.approx(1.7) and np.linalg.norm(first - (1.0, 1.0, 1.9)) < 0.3


def test_after_giving_a_segment_up_for_a_parked_peer_the_next_path_goes_round_it_when_the_map_has_room() -> None:
    hall = OccupancyGrid(np.zeros(3), 0.2, np.zeros((50, 20, 15), dtype=bool))  # 10 x 4 x 3 m, open
    events: list[dict[str, Any]] = []
    exploration = _exploration(events)
    exploration.grid = SimpleNamespace(planning_grid=hall, connected=_JOINED)  # type: ignore[assignment]
    exploration.position = lambda: (0.5, 2.0, 1.5)
    goal, peer = (9.5, 2.0, 1.5), Neighbour(2, (5.0, 2.0, 1.5), (0.0, 0.0, 0.0), (5.0, 2.0, 1.5))
    flight = SimpleNamespace(blocked_by=(peer, time.monotonic()))
    around = exploration._parked_in_the_way(flight)  # type: ignore[arg-type]
    assert around == peer.position
    path = asyncio.run(exploration._plan(goal, around=around))
    assert path is not None and path[-1] == goal
    assert path_clearance([exploration.position(), *path], peer.position) >= PASS_CLEARANCE_M - 1e-9
    assert events[-1]["event"] == "path" and events[-1]["around"] == list(peer.position)

    corridor = OccupancyGrid(np.zeros(3), 0.2, np.ones((50, 20, 15), dtype=bool))
    corridor.occupied[:, 10, 7] = False  # one row of safe cells: no way round
    exploration.grid = SimpleNamespace(planning_grid=corridor, connected=_JOINED)  # type: ignore[assignment]
    exploration.position = lambda: (0.5, 2.1, 1.5)
    # no way round: the plain path, where it passes the peer far enough not to hold for it again
    plain = asyncio.run(exploration._plan((9.5, 2.1, 1.5), around=(5.0, 2.7, 1.5)))
    assert plain == [(9.5, 2.1, 1.5)]
    # ... and no path for now where the only way passes through it: the peer waits for this drone to pass, and
    # this drone would hold for it again (office, 3 drones: both held for 5 minutes, a refuge in a doorway)
    assert asyncio.run(exploration._plan((9.5, 2.1, 1.5), around=(5.0, 2.1, 1.5))) is None
    assert events[-1]["event"] == "no_path" and "waiting at [5.0, 2.1, 1.5]" in events[-1]["reason"]

    flight.blocked_by = (peer, time.monotonic() - PARKED_PEER_S - 1.0)
    assert exploration._parked_in_the_way(flight) is None  # type: ignore[arg-type]  # too long ago


def path_clearance(path: list[Any], point: Any) -> float:
    points = np.concatenate([np.linspace(a, b, 50) for a, b in zip(path[:-1], path[1:])])
    return float(np.linalg.norm(points - np.asarray(point), axis=1).min())


def _round_a_wall_end(wall_to_x: float, events: list[dict[str, Any]]) -> tuple[Exploration, np.ndarray]:
    """An exploration on a 2.4 x 2.4 m grid at 0.2 m (one layer at 1.4-1.6 m) with a wall from x 0 to
    `wall_to_x` at y 1.0-1.2 m, flying to a target at (0.5, 1.9) round the wall's end; and the grid's walls."""
    walls = np.zeros((12, 12, 1), dtype=bool)
    walls[: round(wall_to_x / 0.2), 5, 0] = True
    grid = OccupancyGrid(np.array([0.0, 0.0, 1.4]), 0.2, walls)
    exploration = _exploration(events)
    exploration.grid = SimpleNamespace(  # type: ignore[assignment]  # only these two are read
        planning_grid=grid, is_frontier_near=lambda point, radius: True, connected=_JOINED
    )
    exploration.target = Target((0.5, 1.9, 1.5), (0.3, 2.2, 1.5), "leader")
    return exploration, walls


def test_a_path_is_checked_from_the_drone_on_not_back_to_the_waypoints_it_passed() -> None:
    events: list[dict[str, Any]] = []
    exploration, walls = _round_a_wall_end(1.6, events)
    grid = exploration.grid.planning_grid  # type: ignore[union-attr]
    exploration.position = lambda: (1.2, 1.9, 1.5)  # on the last leg, west, back past the wall's end
    flight = SimpleNamespace(path_ahead=[(0.5, 1.9, 1.5)], setpoint=None)  # passed: (0.5, 0.5), (1.9, 0.5), ...
    exploration.flight = flight  # type: ignore[assignment]
    whole = [(0.5, 0.5, 1.5), (1.9, 0.5, 1.5), (1.9, 1.9, 1.5), (0.5, 1.9, 1.5)]
    assert path_is_free(grid, whole) and not path_is_free(grid, [(1.2, 1.9, 1.5), *whole])
    exploration._check_path()
    assert [e["event"] for e in events] == []  # the line back to (0.5, 0.5) crosses the wall: not our way
    assert not exploration.retarget.is_set()

    walls[4, 9, 0] = True  # now something on the way ahead, at (0.9, 1.9)
    exploration._check_path()
    assert [e["event"] for e in events] == ["path_blocked"]
    assert exploration.retarget.is_set()


def test_a_drone_cutting_a_corner_is_checked_along_its_carrot_not_straight_to_the_next_waypoint() -> None:
    events: list[dict[str, Any]] = []
    exploration, walls = _round_a_wall_end(1.8, events)  # the path goes round its end at x 1.9
    grid = exploration.grid.planning_grid  # type: ignore[union-attr]
    here, carrot, ahead = (1.6, 0.6, 1.5), (1.9, 0.9, 1.5), [(1.9, 1.9, 1.5), (0.5, 1.9, 1.5)]
    exploration.position = lambda: here  # inside the corner at (1.9, 0.5), its carrot already on the next leg
    exploration.flight = SimpleNamespace(path_ahead=ahead, setpoint=carrot)  # type: ignore[assignment]
    assert not grid.segment_is_free(here, ahead[0])  # straight to the next waypoint: through the wall's end
    exploration._check_path()
    assert [e["event"] for e in events] == [] and not exploration.retarget.is_set()

    walls[9, 9, 0] = True  # now something on the way ahead, at (1.9, 1.9)
    exploration._check_path()
    assert [e["event"] for e in events] == ["path_blocked"]


def test_a_drone_whose_way_to_its_carrot_is_now_blocked_brakes_and_one_blocked_farther_on_does_not() -> None:
    """The map changed under the path: a wall mapped late, between the drone and the setpoint it flies to now.
    Until the new path comes the autopilot keeps that setpoint, so the drone must brake (gen:2: it flew on into
    the wall, 0.85 s after the block was seen)."""
    events: list[dict[str, Any]] = []
    exploration, walls = _round_a_wall_end(1.6, events)
    exploration.position = lambda: (1.9, 1.9, 1.5)  # round the wall's end, flying west on the last leg
    exploration.flight = SimpleNamespace(path_ahead=[(0.5, 1.9, 1.5)], setpoint=(1.3, 1.9, 1.5))  # type: ignore[assignment]
    walls[3, 9, 0] = True  # at (0.7, 1.9): beyond the carrot
    assert exploration._check_path() is False
    assert events[-1]["event"] == "path_blocked" and events[-1]["brake"] is False
    walls[3, 9, 0], walls[7, 9, 0] = False, True  # at (1.5, 1.9): between the drone and its carrot
    assert exploration._check_path() is True
    assert events[-1]["event"] == "path_blocked" and events[-1]["brake"] is True


def test_braking_holds_the_drone_where_it_is_and_the_next_path_starts_there() -> None:
    autopilot = FakeAutopilot()
    flight = Flight(autopilot, load_config().agent, lambda *a, **kw: None)  # type: ignore[arg-type]
    autopilot.telemetry.position = (3.0, 2.0, 1.5)
    flight._carrot = (4.2, 2.0, 1.5)
    asyncio.run(flight.brake())
    assert flight.setpoint == (3.0, 2.0, 1.5) and autopilot.visited[-1] == (3.0, 2.0, 1.5)


class _FakeFlight:
    """Records what the exploration flies; every path is reached and every look lasts its full time (or until
    interrupted). Only the calls `Exploration.fly` makes."""

    def __init__(self, exploration: Exploration, on_look: Any = None) -> None:
        self.exploration, self.on_look, self.looks, self.paths = exploration, on_look, [], []
        self.path_ahead: list[Any] = []
        self.blocked_by = None
        self.ap = type("AP", (), {"telemetry": type("T", (), {"yaw_deg": 0.0})()})()

    async def fly_path(self, path: list[Any], stop: asyncio.Event, interrupt: asyncio.Event | None = None) -> bool:
        self.paths.append(path)
        return True

    async def face(
        self, point: Any, seconds: float, stop: asyncio.Event, interrupt: asyncio.Event | None = None
    ) -> None:
        self.looks.append((point, list(self.exploration.visited)))
        if self.on_look is not None:
            self.on_look(point)
        await asyncio.sleep(0)


async def test_a_target_counts_as_visited_when_its_look_starts_so_the_next_is_decided_meanwhile() -> None:
    """An explorer's next target takes two decisions (its report, then its leader's assignment): decided only
    after the look, every target cost most of a second of hovering."""

    exploration = _exploration([])
    exploration.grid = SimpleNamespace(  # type: ignore[assignment]
        planning_grid=OccupancyGrid(np.zeros(3), 0.2, np.zeros((20, 20, 15), bool)), connected=_JOINED
    )
    first = Target((1.0, 1.0, 1.5), (1.5, 1.0, 1.5), "leader")
    second = Target((3.0, 3.0, 1.5), (3.5, 3.0, 1.5), "leader")
    woken_during_look: list[bool] = []

    def look(point: Any) -> None:
        if point == first.point:
            woken_during_look.append(exploration.wake.is_set() and exploration.core.arrived)
            _give(exploration, second)  # the leader's next assignment arrives while we look
        elif point == second.point:
            exploration._finish("done")

    flight = _FakeFlight(exploration, look)
    _give(exploration, first)
    exploration._decisions = asyncio.create_task(asyncio.sleep(3600))  # no decision loop here
    exploration.fly = Exploration.fly.__get__(exploration)
    stop = asyncio.Event()
    try:
        await asyncio.wait_for(_fly_without_decisions(exploration, flight, stop), timeout=10.0)
    finally:
        await exploration.close()
    assert flight.looks[0] == (first.point, [first.viewpoint])  # visited before the look, and asked for more
    assert woken_during_look == [True]
    assert [p[-1] for p in flight.paths[:2]] == [first.viewpoint, second.viewpoint]  # straight on to the next
    assert exploration.visited[:2] == [first.viewpoint, second.viewpoint]


async def _fly_without_decisions(exploration: Exploration, flight: Any, stop: asyncio.Event) -> None:
    """`Exploration.fly` with the decision loop it starts replaced by nothing, and no flight home."""
    exploration.settings = exploration.settings.model_copy(update={"return_home": False})

    async def no_decisions() -> None:
        await asyncio.sleep(3600)

    exploration.decide_forever = no_decisions  # type: ignore[method-assign]
    await exploration.fly(flight, stop)  # type: ignore[arg-type]


async def test_waiting_for_a_target_ends_as_soon_as_one_comes() -> None:
    """A drone with no target turns and maps in WAIT_FOR_TARGET_S looks; a new target ends the look at once."""

    class Telemetry:
        position = (0.0, 0.0, 1.5)
        yaw_deg = 0.0
        telemetry_age_s = 0.0
        battery = 1.0

    class AP:
        telemetry = Telemetry()
        telemetry_age_s = 0.0

        async def set_setpoint(self, position: Any, yaw: float) -> None:
            pass

        def taken_over_by(self) -> None:
            return None

    flight = Flight.__new__(Flight)  # only what `face` reads
    flight.ap = AP()  # type: ignore[assignment]
    flight._carrot = None
    flight.heading_to = None
    flight.separation_m = 0.0
    flight.neighbours = list  # type: ignore[assignment]
    flight._last_check = time.monotonic()
    flight._judge_telemetry_after = 0.0
    flight.airborne = True
    flight.phase, flight.battery_low = Phase.FLYING, False
    flight.settings = load_config().agent
    flight.log = lambda *a, **k: None  # type: ignore[assignment]
    interrupt = asyncio.Event()
    asyncio.get_running_loop().call_later(0.2, interrupt.set)
    started = asyncio.get_running_loop().time()
    await flight.face((1.0, 0.0, 1.5), 30.0, asyncio.Event(), interrupt=interrupt)
    assert asyncio.get_running_loop().time() - started < 5.0  # not the 30 s look


def _in_the_room(states: np.ndarray) -> tuple[Exploration, ExplorationGrid, list[dict[str, Any]]]:
    """An exploration at (1, 3, 1.5) in the synthetic room's grid of `states`, and the events it logs."""
    grid = ExplorationGrid.from_states((0.0, 0.0, 0.0), 0.2, states, ExploreSettings(body_height_m=0.0), 0.0, 3.0)
    events: list[dict[str, Any]] = []
    exploration = _exploration(events)
    exploration.grid = grid
    exploration.position = lambda: (1.0, 3.0, 1.5)
    return exploration, grid, events


def test_a_target_whose_viewpoint_is_blocked_here_is_looked_at_from_a_place_this_map_allows() -> None:
    """A viewpoint from another drone's report can be blocked in this drone's map; the target's point can often
    still be seen from a safe cell nearby."""

    states = room_states(known_to_x=8.0)
    set_states(states, (3.0, 2.6, 1.2), (3.4, 3.0, 1.8), OCCUPIED)  # a block where the reporter saw free space
    exploration, grid, events = _in_the_room(states)
    target = Target((3.1, 2.9, 1.5), (3.9, 2.9, 1.5), "leader")
    assert asyncio.run(exploration._plan(target.viewpoint)) is None
    path = asyncio.run(exploration._plan_to_another_viewpoint(target))
    assert path is not None
    seen_from = path[-1]
    assert grid.planning_grid.is_free(seen_from)
    assert np.linalg.norm(np.subtract(seen_from, target.point)) <= grid.settings.reach_m + 1e-9
    assert events[-2]["event"] == "viewpoint_moved" and events[-2]["to"] == [round(v, 2) for v in seen_from]


async def test_a_peer_parked_at_the_viewpoint_sends_the_drone_to_look_from_elsewhere() -> None:
    """Two drones that picked viewpoints 0.3 m apart (uncoordinated, box, 2 drones): the higher id stepped aside to
    a refuge beside the lower id's viewpoint and waited for it to pass; the lower id held for it, gave the segment
    up, planned round it to the same viewpoint and held again, every 8 s until the mission's time ran out."""

    exploration, grid, events = _in_the_room(room_states(known_to_x=8.0))
    target = Target((3.1, 3.1, 1.5), (3.7, 3.1, 1.5), "self")
    parked = (3.1, 3.3, 1.5)  # the refuge, 0.2 m off the viewpoint
    assert grid.planning_grid.is_free(target.viewpoint) and grid.planning_grid.is_free(parked)
    exploration.target = target

    class Parked(_FakeFlight):
        async def fly_path(self, path: list[Any], stop: asyncio.Event, interrupt: asyncio.Event | None = None) -> bool:
            self.paths.append(path)
            exploration._finish("done")  # one path is all this test looks at
            return False

    flight = Parked(exploration)
    flight.blocked_by = (Neighbour(2, parked, (0.0, 0.0, 0.0), target.viewpoint), time.monotonic())  # type: ignore[assignment]
    await asyncio.wait_for(_fly_without_decisions(exploration, flight, asyncio.Event()), timeout=10.0)
    await exploration.close()
    [path] = flight.paths
    seen_from = path[-1]
    assert math.dist(seen_from, parked) >= PASS_CLEARANCE_M - 1e-9  # not where the peer waits
    assert grid.planning_grid.is_free(seen_from)
    assert math.dist(seen_from, target.point) <= grid.settings.reach_m + 1e-9
    assert path_clearance([exploration.position(), *path], parked) >= PASS_CLEARANCE_M - 1e-9  # and round it
    assert [e["event"] for e in events].count("viewpoint_moved") == 1


async def test_a_drone_whose_target_was_dropped_waits_for_the_next_instead_of_spinning() -> None:
    """A target dropped as explored sets `retarget`; left set, the wait for the next target ended at once, the
    flight loop spun without yielding and the agent hung (a 3-drone office mission)."""

    exploration = _exploration([])
    exploration.grid = SimpleNamespace(in_pocket=lambda here: False)  # type: ignore[assignment]
    calls = []

    class Waiting(_FakeFlight):
        async def face(
            self, point: Any, seconds: float, stop: asyncio.Event, interrupt: asyncio.Event | None = None
        ) -> None:
            calls.append(point)
            if interrupt is not None and interrupt.is_set():
                await asyncio.sleep(0)  # the real look returns at once, without even this
                return
            try:
                await asyncio.wait_for(interrupt.wait() if interrupt else asyncio.sleep(seconds), seconds)
            except TimeoutError:
                pass

    exploration.target = None
    exploration.retarget.set()  # as `_check_path` leaves it when the target's frontier is gone
    flying = asyncio.create_task(_fly_without_decisions(exploration, Waiting(exploration), asyncio.Event()))
    await asyncio.sleep(0.3)
    exploration._finish("done")
    await asyncio.wait_for(flying, timeout=5.0)
    await exploration.close()
    assert 1 <= len(calls) <= 2  # one wait of WAIT_FOR_TARGET_S (0.5 s), ended by `done`


async def test_a_drone_in_a_pocket_gets_out_before_it_calls_its_target_unreachable() -> None:
    """From a pocket every plan fails after a few cells: counted as unreachable, every target was given up."""
    events: list[dict[str, Any]] = []
    exploration = _exploration(events)
    out = (2.0, 1.0, 1.5)

    class PocketGrid:
        planning_grid = OccupancyGrid(np.zeros(3), 0.2, np.ones((20, 20, 15), bool))  # no plan succeeds
        pocket = True

        def in_pocket(self, position: Any) -> bool:
            return self.pocket

        def escape(self, position: Any) -> Any:
            return out

        def connected(self, a: Any, b: Any) -> bool:
            return _JOINED(a, b)

        def viewpoint_for(self, point: Any, position: Any, keep_off: Any = None, keep_off_m: float = 0.0) -> None:
            return None

        def gain_at(self, points: Any) -> np.ndarray:
            return np.zeros(len(points))

    grid = PocketGrid()
    exploration.grid = grid  # type: ignore[assignment]

    class Escaping(_FakeFlight):
        async def fly_path(self, path: list[Any], stop: asyncio.Event, interrupt: asyncio.Event | None = None) -> bool:
            self.paths.append(path)
            grid.pocket = False  # out: the next failure counts
            return True

        async def face(
            self, point: Any, seconds: float, stop: asyncio.Event, interrupt: asyncio.Event | None = None
        ) -> None:
            exploration._finish("done")  # waiting for a new target: end the test's mission
            await asyncio.sleep(0)

    flight = Escaping(exploration)
    _give(exploration, Target((5.0, 1.0, 1.5), (5.5, 1.0, 1.5), "leader"))
    await asyncio.wait_for(_fly_without_decisions(exploration, flight, asyncio.Event()), timeout=10.0)
    await exploration.close()
    assert flight.paths == [[out]]  # first out of the pocket ...
    assert [u.viewpoint for u in exploration.core.unreachable] == [(5.0, 1.0, 1.5)]  # ... then one failure counted
    assert [e["event"] for e in events].count("in_pocket") == 1


async def test_a_drone_with_no_target_in_a_pocket_gets_out_instead_of_waiting() -> None:
    """From its take-off spot, under the cone its camera never saw, a drone may have no frontier worth a target in
    sight: waiting there for one waited the whole flight (gen:11, one drone, 8.7 % explored)."""
    events: list[dict[str, Any]] = []
    exploration = _exploration(events)
    out = (2.0, 1.0, 1.5)
    looks: list[Any] = []

    class PocketGrid:
        pocket = True

        def in_pocket(self, position: Any) -> bool:
            return self.pocket

        def escape(self, position: Any) -> Any:
            return out

        def connected(self, a: Any, b: Any) -> bool:
            return _JOINED(a, b)

    grid = PocketGrid()
    exploration.grid = grid  # type: ignore[assignment]

    class Escaping(_FakeFlight):
        async def fly_path(self, path: list[Any], stop: asyncio.Event, interrupt: asyncio.Event | None = None) -> bool:
            self.paths.append(path)
            grid.pocket = False
            return True

        async def face(
            self, point: Any, seconds: float, stop: asyncio.Event, interrupt: asyncio.Event | None = None
        ) -> None:
            looks.append(point)
            exploration._finish("done")
            await asyncio.sleep(0)

    flight = Escaping(exploration)
    exploration.target = None
    await asyncio.wait_for(_fly_without_decisions(exploration, flight, asyncio.Event()), timeout=10.0)
    await exploration.close()
    assert flight.paths[0] == [out]  # out first, then the wait (out of the pocket: a look round)
    assert len(looks) == 1
    assert [e["event"] for e in events].count("in_pocket") == 1


@pytest.mark.parametrize("idle_home_s", [0.0, 600.0])
async def test_a_drone_left_without_a_target_heads_home_until_a_new_target_comes(idle_home_s: float) -> None:
    """A drone with nothing left to explore flew home only once its cluster was done: the return (15-24 s in the
    office) came after the last frontier. Idle for `idle_home_s`, it heads home; a new target turns it round."""
    events: list[dict[str, Any]] = []
    exploration = _exploration(events, **{"explore.idle_home_s": idle_home_s})
    exploration.position = lambda: (3.0, 3.0, 1.5)
    exploration.grid = SimpleNamespace(  # type: ignore[assignment]  # only these are read
        planning_grid=OccupancyGrid(np.zeros(3), 0.2, np.zeros((25, 25, 15), bool)),
        in_pocket=lambda here: False,
        connected=_JOINED,
    )
    above_home = (0.0, 0.0, exploration.config.agent.altitude_m)
    late = Target((4.0, 1.0, 1.5), (4.5, 1.0, 1.5), "leader")

    class Homing(_FakeFlight):
        async def fly_path(self, path: list[Any], stop: asyncio.Event, interrupt: asyncio.Event | None = None) -> bool:
            self.paths.append(path)
            if path[-1] == above_home and exploration.target is None and not exploration.done:
                _give(exploration, late)  # on the way home, the leader finds work for it after all
                return not (interrupt is not None and interrupt.is_set())
            if path[-1] == late.viewpoint:
                exploration._finish("done")
            return True

        async def face(
            self, point: Any, seconds: float, stop: asyncio.Event, interrupt: asyncio.Event | None = None
        ) -> None:
            if point != late.point:  # waiting: the wait ends with a target after a while
                _give(exploration, late)
            await asyncio.sleep(0)

    flight = Homing(exploration)
    exploration.target = None
    exploration.decide_forever = lambda: asyncio.sleep(3600)  # type: ignore[method-assign,assignment,return-value]
    await asyncio.wait_for(exploration.fly(flight, asyncio.Event()), timeout=10.0)  # type: ignore[arg-type]
    await exploration.close()
    ends = [p[-1] for p in flight.paths]
    headed_home = [e for e in events if e["event"] == "heading_home"]
    if idle_home_s == 0.0:
        assert ends == [above_home, late.viewpoint, above_home]  # home, turned round, home again when done
        assert len(headed_home) == 1
    else:
        assert ends == [late.viewpoint, above_home]  # not idle long enough: waited in place for the target
        assert headed_home == []


@pytest.mark.parametrize(
    ("idle_s", "left_out", "rounds", "heads_home"),
    [
        (0.5, True, 1, True),  # a round since it became idle had nothing for it
        (5.9, False, 3, False),  # between two targets: not idle long enough
        (6.0, False, 2, True),  # idle_home_s through two rounds that did not give it a target
        (6.0, False, 1, False),  # the only round since may have been decided before it became idle
        (20.0, False, 0, False),  # its leader's round is slow (a loaded machine): it waits for it
        (6.0 * IDLE_WITHOUT_ROUNDS, False, 0, True),  # rounds that never come
    ],
)
def test_an_idle_drone_heads_home_when_decisions_found_nothing_for_it_not_when_they_are_slow(
    idle_s: float, left_out: bool, rounds: int, heads_home: bool
) -> None:
    """Hall, 5 drones, 2 cores: decisions took 8-10 s at the median, and on `idle_home_s` (6 s) alone drones
    between two targets flew home and back, the leader four times in two minutes with 60-180 candidates left."""
    assert should_head_home(idle_s, left_out, rounds, idle_home_s=6.0) is heads_home


@pytest.mark.parametrize("left_out", [True, False])
async def test_a_drone_its_leader_found_nothing_for_heads_home_at_once(left_out: bool) -> None:
    """Idle between two targets, a drone waits (`idle_home_s`, here far longer than the test); once a round of
    its leader's made since it became idle found nothing for it, it heads home at once."""
    events: list[dict[str, Any]] = []
    exploration, above_home = _idle_in_the_open(events)
    late = Target((4.0, 1.0, 1.5), (4.5, 1.0, 1.5), "leader")

    class Waiting(_FakeFlight):
        async def fly_path(self, path: list[Any], stop: asyncio.Event, interrupt: asyncio.Event | None = None) -> bool:
            self.paths.append(path)
            exploration._finish("done")
            return True

        async def face(
            self, point: Any, seconds: float, stop: asyncio.Event, interrupt: asyncio.Event | None = None
        ) -> None:
            if left_out:
                exploration._apply(exploration.core.on_assignment(time.monotonic(), 1, NOTHING_FOR_2, leader=1))
            else:
                _give(exploration, late)  # the next target, after a wait
            await asyncio.sleep(0)

    flight = Waiting(exploration)
    exploration.target = None
    exploration.decide_forever = lambda: asyncio.sleep(3600)  # type: ignore[method-assign,assignment,return-value]
    await asyncio.wait_for(exploration.fly(flight, asyncio.Event()), timeout=10.0)  # type: ignore[arg-type]
    await exploration.close()
    first = flight.paths[0][-1]
    assert first == (above_home if left_out else late.viewpoint)
    assert len([e for e in events if e["event"] == "heading_home"]) == (1 if left_out else 0)


async def test_a_round_with_nothing_for_a_drone_made_while_it_looks_at_its_last_target_sends_it_home() -> None:
    """The arrival wakes a decision that counts the target looked at; when it finds nothing for the drone, the
    drone heads home after the look, not a loop later (3.4 s in each of 4 bench missions)."""
    events: list[dict[str, Any]] = []
    exploration, above_home = _idle_in_the_open(events)
    last = Target((4.0, 1.0, 1.5), (4.5, 1.0, 1.5), "leader")

    class Looking(_FakeFlight):
        async def fly_path(self, path: list[Any], stop: asyncio.Event, interrupt: asyncio.Event | None = None) -> bool:
            self.paths.append(path)
            if path[-1] == above_home:
                exploration._finish("done")
            return True

        async def face(
            self, point: Any, seconds: float, stop: asyncio.Event, interrupt: asyncio.Event | None = None
        ) -> None:
            if point == last.point:  # the look: the round the arrival woke comes in meanwhile
                exploration._apply(exploration.core.on_assignment(time.monotonic(), 1, NOTHING_FOR_2, leader=1))
            await asyncio.sleep(0)

    flight = Looking(exploration)
    _give(exploration, last)
    exploration.decide_forever = lambda: asyncio.sleep(3600)  # type: ignore[method-assign,assignment,return-value]
    await asyncio.wait_for(exploration.fly(flight, asyncio.Event()), timeout=10.0)  # type: ignore[arg-type]
    await exploration.close()
    assert [p[-1] for p in flight.paths][:2] == [last.viewpoint, above_home]
    assert [e["event"] for e in events if e["event"] in ("target_reached", "heading_home")] == [
        "target_reached",
        "heading_home",
    ]


def _idle_in_the_open(events: list[dict[str, Any]]) -> tuple[Exploration, Vec3]:
    """Drone 2 at (3, 3, 1.5) in an empty map, waiting far longer for `idle_home_s` than any test; and the point
    above its home."""
    exploration = _exploration(events, **{"explore.idle_home_s": 600.0})
    exploration.position = lambda: (3.0, 3.0, 1.5)
    exploration.grid = SimpleNamespace(  # type: ignore[assignment]  # only these are read
        planning_grid=OccupancyGrid(np.zeros(3), 0.2, np.zeros((25, 25, 15), bool)),
        in_pocket=lambda here: False,
        connected=_JOINED,
    )
    return exploration, (0.0, 0.0, exploration.config.agent.altitude_m)


# leader 1's round for the cluster [1, 2] with a target for itself only
NOTHING_FOR_2 = TargetAssignment(
    leader=1,
    epoch=1,
    round=7,
    members=[1, 2],
    drones=[1],
    viewpoints=as_points([(9.0, 9.0, 1.5)]),
    points=as_points([(9.5, 9.0, 1.5)]),
)


class _CountingViews:
    """`MappingTask.explore_view` on a fixed map, counting the views asked for."""

    def __init__(self) -> None:
        self.views = 0
        self.grid = ExplorationGrid.from_states(
            (0.0, 0.0, 0.0), 0.2, room_states(known_to_x=4.0), ExploreSettings(), floor_z=0.0, top_z=3.0
        )

    async def explore_view(self, floor_z: float, top_z: float, position: Any, obstacles: Any) -> tuple[Any, Any]:
        self.views += 1
        return self.grid, self.grid.frontiers(position)


@pytest.mark.parametrize("reuse_s, views", [(600.0, 1), (0.0, 3)])
async def test_decisions_soon_after_a_view_decide_on_it(reuse_s: float, views: int) -> None:
    """A leader is woken by every member's arrival: a new view each time made it the slowest drone."""
    exploration = _exploration([], **{"explore.view_reuse_s": reuse_s, "explore.strategy": "uncoordinated"})
    mapping = _CountingViews()
    exploration.mapping = mapping  # type: ignore[assignment]  # the one method a decision calls
    exploration.position = lambda: (1.0, 3.0, 1.5)
    for _ in range(3):
        await exploration.decide()
    assert mapping.views == views and exploration.core.loops == 3
    assert exploration.grid is mapping.grid and exploration.target is not None
    summary = exploration.summary()
    assert summary["decisions_on_last_view"] == 3 - views and summary["decision_ms_p50"] is not None
    assert len(exploration.decision_ms) == views  # the decision time is that of decisions on a new view


async def test_the_core_decides_off_the_event_loop_and_what_arrives_meanwhile_waits_for_it(monkeypatch) -> None:
    """A leader's round took up to 2.9 s on a loaded machine, on the event loop: no heartbeat went out, and its
    peers took it for lost (hall, 5 drones, 2 cores). The core decides in the decision thread now; it is not
    thread-safe, so an assignment heard meanwhile is handed to it once it has decided, and the flight waits."""
    exploration = _exploration([], **{"explore.view_reuse_s": 0.0})
    exploration.mapping = _CountingViews()  # type: ignore[assignment]
    exploration.bus = SimpleNamespace(keys=SimpleNamespace(agent_id_of=lambda key: 1))  # type: ignore[assignment]
    calls: list[str] = []
    deciding, release = threading.Event(), threading.Event()

    def slow_decide(now: float, situation: Any) -> Effects:
        calls.append("decide on the loop" if threading.current_thread() is threading.main_thread() else "decide")
        deciding.set()
        release.wait(timeout=10.0)
        return Effects()

    monkeypatch.setattr(exploration.core, "decide", slow_decide)
    monkeypatch.setattr(exploration.core, "on_assignment", lambda *args: calls.append("assignment") or Effects())
    decision = asyncio.create_task(exploration.decide())
    assert await asyncio.to_thread(deciding.wait, 10.0)
    exploration._on_assignment("swarm/default/targets/1", NOTHING_FOR_2)  # the event loop runs: this test does
    flight_waits = asyncio.create_task(exploration._core_ready())
    await asyncio.sleep(0)
    assert calls == ["decide"] and not flight_waits.done()
    release.set()
    await asyncio.wait_for(decision, timeout=10.0)
    await asyncio.wait_for(flight_waits, timeout=10.0)
    assert calls == ["decide", "assignment"]
    exploration._on_assignment("swarm/default/targets/1", NOTHING_FOR_2)  # not deciding: at once
    assert calls == ["decide", "assignment", "assignment"]


class _HomewardFlight:
    """A flight that records the paths it is given to fly; each is flown unless `refuse` says how many to refuse."""

    def __init__(self, flown_back: list[tuple[float, float, float]], refuse: int = 0) -> None:
        self.flown_back = flown_back
        self.refuse = refuse
        self.paths: list[list[tuple[float, float, float]]] = []

    def way_back(self) -> list[tuple[float, float, float]]:
        return list(self.flown_back)

    async def fly_path(self, path: list[tuple[float, float, float]], stop: asyncio.Event, **_: Any) -> bool:
        self.paths.append(path)
        if self.refuse:
            self.refuse -= 1
            return False
        return True


async def test_with_no_path_home_on_the_map_the_drone_flies_back_the_way_it_came(monkeypatch) -> None:
    """Home's cell can look blocked on the map (a wall stub half a metre away, inflated): the drone must still get
    home, by the legs it flew, not land where it is."""
    events: list[dict[str, Any]] = []
    exploration = _exploration(events)
    exploration.grid = SimpleNamespace(  # type: ignore[assignment]  # a map on which `_plan` finds nothing
        planning_grid=SimpleNamespace(is_free=lambda point: True), connected=lambda a, b: False
    )

    async def no_path(goal: Any, **_: Any) -> None:
        return None

    monkeypatch.setattr(exploration, "_plan", no_path)
    way_back = [(3.0, 1.0, 1.5), (1.0, 1.0, 1.5), (0.0, 0.0, 1.5)]
    flight = _HomewardFlight(way_back)
    await exploration._return(flight, asyncio.Event(), (0.0, 0.0, 0.0))  # type: ignore[arg-type]
    assert flight.paths == [way_back]
    assert [e for e in events if e["event"] == "retrace_home"] == [
        {"event": "retrace_home", "reason": "no path home", "waypoints": 3}
    ]
    assert not [e for e in events if e["event"] == "land_in_place"]

    events.clear()
    blocked_both_ways = _HomewardFlight(way_back, refuse=1)
    await exploration._return(blocked_both_ways, asyncio.Event(), (0.0, 0.0, 0.0))  # type: ignore[arg-type]
    [landed] = [e for e in events if e["event"] == "land_in_place"]
    assert landed["reason"].startswith("no path home")


async def test_a_drone_its_map_shut_in_flies_back_only_as_far_as_the_first_waypoint_the_map_leads_home_from() -> None:
    """The map can close a narrow door behind a drone (its jambs, mapped more fully, leave no safe cell in it):
    the drone goes back the way it came through the door, then home on the map's way, not the whole way back."""
    exploration, grid, events = _in_the_room(room_states(known_to_x=8.0, wall_x=4.0, door=False))
    exploration.position = lambda: (6.0, 3.0, 1.5)  # east of the wall; home is west of it
    above = (1.0, 3.0, 0.0 + exploration.config.agent.altitude_m)
    assert not grid.connected(exploration.position(), above)
    through_the_door = [(6.5, 3.0, 1.5), (5.0, 3.0, 1.5), (4.1, 3.0, 1.5), (3.0, 3.0, 1.5), (2.0, 4.0, 1.5)]
    flight = _HomewardFlight([*through_the_door, above])
    await exploration._return(flight, asyncio.Event(), (1.0, 3.0, 0.0))  # type: ignore[arg-type]
    # (4.1, 3) is in the wall: the first safe waypoint west of it leads home, straight on this map
    assert flight.paths == [[*through_the_door[:4], above]]
    assert [e["waypoints"] for e in events if e["event"] == "retrace_home"] == [5]


async def test_a_drone_with_a_path_home_flies_it_and_lands_in_place_only_after_giving_way_every_time(
    monkeypatch,
) -> None:
    events: list[dict[str, Any]] = []
    exploration = _exploration(events)
    exploration.grid = SimpleNamespace()  # type: ignore[assignment]
    planned = [(2.0, 0.0, 1.5), (0.0, 0.0, 1.5)]

    async def plan(goal: Any, **_: Any) -> list[Any]:
        return list(planned)

    monkeypatch.setattr(exploration, "_plan", plan)
    flight = _HomewardFlight([(9.0, 9.0, 1.5)])
    await exploration._return(flight, asyncio.Event(), (0.0, 0.0, 0.0))  # type: ignore[arg-type]
    assert flight.paths == [planned]  # the map's path, not the way back
    assert not [e for e in events if e["event"] in ("retrace_home", "land_in_place")]

    gives_way = _HomewardFlight([(9.0, 9.0, 1.5)], refuse=99)
    await exploration._return(gives_way, asyncio.Event(), (0.0, 0.0, 0.0))  # type: ignore[arg-type]
    assert gives_way.paths == [planned] * 3  # RETURN_ATTEMPTS plans, never the way back
    assert [e["reason"] for e in events if e["event"] == "land_in_place"] == ["kept giving way"]


def test_a_drone_that_flew_on_while_its_path_was_planned_goes_back_to_its_start_unless_the_way_on_is_clear() -> None:
    """A plan takes up to seconds and the drone flies on to its last carrot meanwhile: from where it is then, the
    straight way to the path's first waypoint was never checked."""
    events: list[dict[str, Any]] = []
    exploration, _ = _round_a_wall_end(1.6, events)  # the wall from x 0 to 1.6 at y 1.0-1.2
    grid = exploration.grid.planning_grid  # type: ignore[union-attr]
    start, goal = (2.1, 0.5, 1.5), (0.5, 1.9, 1.5)
    exploration.position = lambda: start
    planned = asyncio.run(exploration._plan(goal))
    assert planned is not None and grid.segment_is_free(start, planned[0])

    def drifting(to: Vec3) -> Any:
        """The drone is at `start` when the plan starts, and at `to` from then on."""
        calls = iter([start])
        return lambda: next(calls, to)

    under_the_wall = (0.7, 0.5, 1.5)  # flew on west, under the wall: the way to the first waypoint crosses it
    assert not grid.segment_is_free(under_the_wall, planned[0]) and grid.segment_is_free(under_the_wall, start)
    exploration.position = drifting(under_the_wall)
    assert asyncio.run(exploration._plan(goal)) == [start, *planned]
    assert events[-1]["event"] == "path_from_start"

    events.clear()
    a_little_on = (2.1, 0.7, 1.5)  # from here the way on is clear: flown from here
    assert grid.segment_is_free(a_little_on, planned[0])
    exploration.position = drifting(a_little_on)
    assert asyncio.run(exploration._plan(goal)) == planned
    assert [e["event"] for e in events] == ["path"]


def test_a_goal_the_maps_safe_space_does_not_join_to_the_drone_fails_without_a_search(monkeypatch) -> None:
    """A* learns that a goal is cut off only by searching all of the drone's side: 100,000 cells and seconds of
    hovering in a large building."""
    exploration, grid, events = _in_the_room(room_states(known_to_x=8.0, wall_x=4.0, door=False))
    beyond_the_wall = (6.0, 3.0, 1.5)

    def no_search(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("searched")

    monkeypatch.setattr("swarm.agent.exploration.plan_path", no_search)
    assert asyncio.run(exploration._plan(beyond_the_wall)) is None
    assert events[-1]["event"] == "no_path" and "not joined" in events[-1]["reason"]

    monkeypatch.undo()
    exploration, grid, events = _in_the_room(room_states(known_to_x=8.0, wall_x=4.0, door=True))
    path = asyncio.run(exploration._plan(beyond_the_wall))
    assert path is not None and path[-1] == beyond_the_wall  # through the door
