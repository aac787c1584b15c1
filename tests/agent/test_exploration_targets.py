"""`Exploration._set_target`: how a new assignment replaces (or keeps) the drone's current target.

The flight loop knows its target by identity: reaching a target only counts (dwell, "done with it") when the
target it set out for is still the current one. Re-assigning the same spot at every decision loop must therefore
keep the object, or a drone whose leader repeats itself never finishes a target.
"""

from __future__ import annotations

import asyncio
from typing import Any

import pytest

from swarm.agent.exploration import UNREACHABLE_GIVE_UP, UNREACHABLE_RETRY_S, Exploration, Target
from swarm.config import load_config
from swarm.explore.frontiers import Frontier
from swarm.roles.membership import PeerTable


def _exploration(events: list[dict[str, Any]], **overrides: Any) -> Exploration:
    config = load_config(overrides={"agent.id": 2, **overrides})
    return Exploration(
        config, epoch=1, bus=None, peers=PeerTable(2), mapping=None,  # type: ignore[arg-type]  # unused here
        position=lambda: (0.0, 0.0, 1.5), home=lambda: (0.0, 0.0, 0.0), top_z=3.0,
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


def test_the_same_spot_assigned_again_keeps_the_target_object() -> None:
    events: list[dict[str, Any]] = []
    exploration = _exploration(events)
    assert exploration._set_target(Target((1.0, 1.0, 1.5), (1.5, 1.0, 1.5), "self"))
    flying_to = exploration.target
    exploration.retarget.clear()
    kept = exploration._set_target(Target((1.3, 1.2, 1.5), (1.9, 1.2, 1.5), "leader"))  # 0.36 m away
    assert kept is False
    assert exploration.target is flying_to  # the flight loop still recognises it when it arrives
    assert flying_to.viewpoint == (1.0, 1.0, 1.5) and flying_to.point == (1.9, 1.2, 1.5)
    assert flying_to.source == "leader"  # the leader has confirmed it: tau no longer applies
    assert not exploration.retarget.is_set()
    assert (exploration.targets_self_selected, exploration.targets_assigned) == (1, 0)
    assert [e["event"] for e in events] == ["target"]


def test_a_different_spot_replaces_the_target_and_interrupts_the_flight() -> None:
    events: list[dict[str, Any]] = []
    exploration = _exploration(events)
    exploration._set_target(Target((1.0, 1.0, 1.5), (1.5, 1.0, 1.5), "leader"))
    first = exploration.target
    exploration.retarget.clear()
    assert exploration._set_target(Target((4.0, 1.0, 1.5), (4.5, 1.0, 1.5), "leader"))
    assert exploration.target is not first and exploration.target.viewpoint == (4.0, 1.0, 1.5)
    assert exploration.retarget.is_set()
    assert exploration.targets_assigned == 2
    assert [e["event"] for e in events] == ["target", "target"]


def test_a_target_without_a_path_is_kept_from_this_drone_a_while_then_given_up(monkeypatch) -> None:
    events: list[dict[str, Any]] = []
    exploration = _exploration(events)
    clock = [100.0]
    monkeypatch.setattr("swarm.agent.exploration.time.monotonic", lambda: clock[0])
    behind_a_door = Target((5.0, 1.0, 1.5), (5.5, 1.0, 1.5), "leader")
    for _ in range(1, UNREACHABLE_GIVE_UP):
        exploration._set_target(behind_a_door)
        exploration._cannot_reach(behind_a_door)
        assert exploration.target is None and exploration.arrived  # asks for another target now
        assert exploration._recently_unreachable() == [behind_a_door.viewpoint]
        assert exploration.visited == []  # the others may still be sent there
        clock[0] += UNREACHABLE_RETRY_S + 1.0
        assert exploration._recently_unreachable() == []  # and it may be tried again
    exploration._set_target(behind_a_door)
    exploration._cannot_reach(behind_a_door)
    assert exploration.visited == [behind_a_door.viewpoint]  # the last try: nobody is sent there again
    assert events[-1]["event"] == "unreachable_given_up"


def test_a_target_looked_at_is_exhausted_by_its_viewpoint_however_far_its_point_is() -> None:
    """Found in a box mission: a frontier point 0.82 m above its viewpoint (a ceiling corner the camera cannot
    see from below) was assigned, reached and assigned again for 80 s, because what the drone remembered as
    visited was the point, while exhaustion compares viewpoints (`visited_radius_m`, 0.8 m)."""
    exploration = _exploration([])
    ceiling_corner = Target((4.7, 3.9, 1.5), (4.7, 4.1, 2.3), "leader")
    assert exploration._candidates([Frontier(ceiling_corner.point, ceiling_corner.viewpoint, 2.0, 4)])
    exploration._set_target(ceiling_corner)
    exploration._done_with(ceiling_corner)
    assert exploration.visited == [ceiling_corner.viewpoint]
    assert exploration._candidates([Frontier(ceiling_corner.point, ceiling_corner.viewpoint, 2.0, 4)]) == []
    elsewhere = Frontier((8.0, 3.9, 1.5), (7.5, 3.9, 1.5), 2.0, 4)
    assert [c.viewpoint for c in exploration._candidates([elsewhere])] == [elsewhere.viewpoint]


def test_from_a_cell_that_is_not_safe_the_flight_starts_at_the_nearest_safe_cell() -> None:
    from types import SimpleNamespace

    import numpy as np

    from swarm.explore.grid import OccupancyGrid

    blocked = np.zeros((20, 20, 15), dtype=bool)  # 4 x 4 x 3 m at 0.2 m
    blocked[:, :, 9:] = True  # nothing is safe above 1.8 m (under a lintel, say)
    grid = OccupancyGrid(np.zeros(3), 0.2, blocked)
    exploration = _exploration([])
    exploration.grid = SimpleNamespace(planning_grid=grid)  # type: ignore[assignment]  # only the grid is read
    goal = (3.0, 1.0, 1.5)

    exploration.position = lambda: (1.0, 1.0, 1.5)  # a safe cell: the path's start is the drone itself
    path = asyncio.run(exploration._plan(goal))
    assert path == [goal]

    exploration.position = lambda: (1.0, 1.0, 1.9)  # stepped up out of the safe cells
    path = asyncio.run(exploration._plan(goal))
    assert path is not None and len(path) == 2 and path[-1] == goal
    first = np.array(path[0])  # first down to the nearest safe cell centre (the top safe layer, 1.6-1.8 m)
    assert grid.is_free(first) and first[2] == pytest.approx(1.7) and np.linalg.norm(first - (1.0, 1.0, 1.9)) < 0.3


def test_a_path_is_checked_from_the_drone_on_not_back_to_the_waypoints_it_passed() -> None:
    from types import SimpleNamespace

    import numpy as np

    from swarm.explore.grid import OccupancyGrid

    walls = np.zeros((12, 12, 1), dtype=bool)  # 2.4 x 2.4 m at 0.2 m, one layer at 1.4-1.6 m
    walls[:8, 5, 0] = True  # a wall from x 0 to 1.6 m at y 1.0-1.2 m: the path goes round its end
    grid = OccupancyGrid(np.array([0.0, 0.0, 1.4]), 0.2, walls)
    events: list[dict[str, Any]] = []
    exploration = _exploration(events)
    exploration.grid = SimpleNamespace(  # type: ignore[assignment]  # only these two are read
        planning_grid=grid, is_frontier_near=lambda point, radius: True)
    exploration.target = Target((0.5, 1.9, 1.5), (0.3, 2.2, 1.5), "leader")
    exploration.position = lambda: (1.2, 1.9, 1.5)  # on the last leg, west, back past the wall's end
    flight = SimpleNamespace(path_ahead=[(0.5, 1.9, 1.5)])  # passed: (0.5, 0.5), (1.9, 0.5), (1.9, 1.9)
    exploration.flight = flight  # type: ignore[assignment]
    from swarm.explore.planner import path_is_free
    whole = [(0.5, 0.5, 1.5), (1.9, 0.5, 1.5), (1.9, 1.9, 1.5), (0.5, 1.9, 1.5)]
    assert path_is_free(grid, whole) and not path_is_free(grid, [(1.2, 1.9, 1.5), *whole])
    exploration._check_path()
    assert [e["event"] for e in events] == []  # the line back to (0.5, 0.5) crosses the wall: not our way
    assert not exploration.retarget.is_set()

    walls[4, 9, 0] = True  # now something on the way ahead, at (0.9, 1.9)
    exploration._check_path()
    assert [e["event"] for e in events] == ["path_blocked"]
    assert exploration.retarget.is_set()
