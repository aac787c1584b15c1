"""Separation between drones: two real MAVSDK flights against the simulator, head-on on the same line, or one
hovering on the other's line.

The drones' `neighbours()` read each other's telemetry directly (in flight, heartbeats carry the same position
and velocity), and `is_clear` asks the world mesh: everything else (autopilot, MAVLink, simulator physics and
collision truth) is the real thing. Without separation the two collide, which shows the scenario is a real
conflict; with it, drone 2 steps out of drone 1's way and both arrive.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable

import numpy as np
import pytest

from swarm.agent.autopilot import Autopilot
from swarm.agent.flight import PARKED_FOR_S, STEP_ASIDE_M, Flight, Neighbour
from swarm.agent.separation import MAX_YIELD_S
from swarm.bus.phase import Phase
from swarm.config import Vec3, gcs_port, load_config
from swarm.sim.worlds import load_world
from tests.agent.fake_autopilot import FakeAutopilot
from tests.agent.mesh_clearance import clear_in
from tests.sim.support import free_port_block, running_sim, sim_config

pytestmark = pytest.mark.timeout(150)

WEST, EAST = (1.0, 2.0, 0.0), (3.6, 2.0, 0.0)  # the box's open strip south of its wall stub
ALTITUDE = 1.5


@pytest.mark.sim
def test_a_silent_drone_is_an_obstacle_held_for_only_when_our_segment_would_touch_it() -> None:
    # Drone 1 went silent (agent killed, vehicle hovering). Giving way to it by id would never end (a soak
    # mission livelocked so for 400 s); holding for it is right only when the segment passes through it.
    silent = [Neighbour(1, (2.0, 0.0, 1.5), (0.0, 0.0, 0.0), silent=True)]
    flight = _offline_flight(2, lambda: silent)
    here = np.array([1.0, 0.0, 1.5])
    assert flight._rival(here, here) is None  # hovering near it: no stepping aside
    assert flight._rival(here, np.array([3.0, 0.0, 1.5])) is not None  # straight through it: hold
    assert flight._rival(here, np.array([2.0, 1.5, 1.5])) is None  # passing 0.83 m off it: carry on
    parked_there = [n._replace(silent=False) for n in silent]  # alive, hovering with no segment to fly
    flight.neighbours = lambda: parked_there
    assert flight._rival(here, here) is None  # it will not move off: an obstacle, not a drone to give way to
    assert flight._rival(here, np.array([3.0, 0.0, 1.5])) == parked_there[0]._replace(silent=True)  # hold
    flying = [n._replace(silent=False, heading_to=(2.0, 3.0, 1.5)) for n in silent]
    flight.neighbours = lambda: flying
    assert flight._rival(here, here) == flying[0]  # the same drone alive and on its way, a lower id: give way


@pytest.mark.sim
def test_a_drone_coming_down_to_land_is_an_obstacle_held_for_only_when_our_way_passes_through_its_descent() -> None:
    # Homes 1.5 m apart: drone 2 heading home gave way to drone 1 landing next to it, and waited until drone 1
    # touched down (gen:1, 3 drones: 8 s, then its yield timed out). A drone coming straight down goes nowhere
    # our way; what matters is whether our segment passes under it.
    landing = Neighbour(1, (2.0, 0.0, 1.5), (0.0, 0.0, -0.7))
    flight = _offline_flight(2, lambda: [landing])
    here = np.array([1.0, 0.0, 1.5])
    assert flight._rival(here, np.array([1.0, 1.5, 1.5])) is None  # beside its column: carry on
    assert flight._rival(here, np.array([3.0, 0.0, 1.5])) == landing._replace(silent=True)  # through it: hold
    low = np.array([1.0, 0.0, 0.5])
    # under where it is now by 1 m, but where it will be in a second: hold
    assert flight._rival(low, np.array([3.0, 0.0, 0.5])) == landing._replace(silent=True)
    drifting = landing._replace(velocity=(0.5, 0.0, -0.7))  # on its way somewhere, a lower id: give way
    flight.neighbours = lambda: [drifting]
    assert flight._rival(here, np.array([1.0, 1.5, 1.5])) == drifting


async def _encounter(separation_m: float, hover_in_the_way: bool = False) -> tuple[dict, list[Flight], list[bool]]:
    """Drone 1 flies WEST -> EAST at ALTITUDE; drone 2 flies EAST -> WEST on the same line, or, with
    `hover_in_the_way`, hovers (looking about, as a drone waiting for a target does) on drone 1's line."""
    spawns = [WEST, (2.3, 2.0, 0.0)] if hover_in_the_way else [WEST, EAST]
    config = sim_config(free_port_block(), **{"mission.drones": 2, "sim.spawns": spawns})
    world = load_world("box")
    with running_sim(config, world) as server:
        flights: list[Flight] = []

        def neighbours_of(k: int):
            def neighbours() -> list[Neighbour]:
                other = flights[1 - k]
                tel = other.ap.telemetry
                return [Neighbour(2 - k, tel.position, tel.velocity, other.heading_to)] if other.airborne else []

            return neighbours

        for k in range(2):
            autopilot = Autopilot(f"udpin://127.0.0.1:{gcs_port(config.sim, k + 1)}", config.mission.origin)
            settings = config.agent.model_copy(update={"id": k + 1, "altitude_m": ALTITUDE, "hover_s": 0.0})
            flights.append(
                Flight(
                    autopilot,
                    settings,
                    lambda *a, **kw: None,
                    separation_m=separation_m,
                    neighbours=neighbours_of(k),
                    is_clear=clear_in(world),
                )
            )
        arrived = [False, False]
        both_up = asyncio.Event()

        def mission_to(k: int, goal: tuple[float, float, float]):
            async def mission(flight: Flight, stop: asyncio.Event) -> None:
                if all(f.airborne for f in flights):
                    both_up.set()
                await asyncio.wait_for(both_up.wait(), 60)
                target = (goal[0], goal[1], ALTITUDE)
                for _ in range(3):  # a drone that gave way too long gets its path again, as exploration replans
                    if await flight.fly_path([target], stop):
                        arrived[k] = True
                        return

            return mission

        async def hover(flight: Flight, stop: asyncio.Event) -> None:
            if all(f.airborne for f in flights):
                both_up.set()
            await asyncio.wait_for(both_up.wait(), 60)
            end = asyncio.get_running_loop().time() + 12.0
            while asyncio.get_running_loop().time() < end and not arrived[0]:
                await flight.face((2.3, 5.0, ALTITUDE), 1.0, stop)
            arrived[1] = True

        stop = asyncio.Event()
        missions = [mission_to(0, EAST), hover if hover_in_the_way else mission_to(1, WEST)]
        try:
            await asyncio.gather(*(f.run(m, stop) for f, m in zip(flights, missions)))
        finally:
            for flight in flights:
                await flight.ap.close()
        return server.status(), flights, arrived


def _drone_collisions(status: dict) -> list[dict]:
    return [e for e in status["collision_events"] if e["kind"] == "drone"]


@pytest.mark.sim
def test_without_separation_the_head_on_drones_collide() -> None:
    status, _, arrived = asyncio.run(_encounter(separation_m=0.0))
    assert arrived == [True, True]
    assert _drone_collisions(status), status["collision_events"]


@pytest.mark.sim
def test_the_higher_id_steps_aside_and_both_drones_arrive_without_touching() -> None:
    status, flights, arrived = asyncio.run(_encounter(separation_m=1.2))
    assert status["collision_events"] == []
    assert arrived == [True, True]
    assert flights[0].yields == 0 and flights[1].yields >= 1
    for flight, goal in zip(flights, (EAST, WEST)):
        x, y, _ = flight.ap.telemetry.position
        assert math.hypot(x - goal[0], y - goal[1]) < 0.6


@pytest.mark.sim
def test_a_hovering_higher_id_in_the_way_moves_off_the_line() -> None:
    status, flights, arrived = asyncio.run(_encounter(separation_m=1.2, hover_in_the_way=True))
    assert status["collision_events"] == []
    assert arrived == [True, True]
    assert flights[0].yields == 0 and flights[1].yields >= 1
    x, y, _ = flights[0].ap.telemetry.position
    assert math.hypot(x - EAST[0], y - EAST[1]) < 0.6


async def _come_down_onto_a_grounded_drone() -> tuple[dict, Flight, list[dict]]:
    """Drone 1 flies from WEST to above drone 2, which sits on the ground where a failsafe put it, and lands."""
    grounded = (2.3, 2.0, 0.0)
    config = sim_config(free_port_block(), **{"mission.drones": 2, "sim.spawns": [WEST, grounded]})
    world = load_world("box")
    events: list[dict] = []
    with running_sim(config, world) as server:
        autopilot = Autopilot(f"udpin://127.0.0.1:{gcs_port(config.sim, 1)}", config.mission.origin)
        settings = config.agent.model_copy(update={"id": 1, "altitude_m": ALTITUDE, "hover_s": 0.0})

        def log(event: str, **fields) -> None:
            events.append({"event": event, **fields})

        flight = Flight(
            autopilot,
            settings,
            log,
            separation_m=1.2,
            is_clear=clear_in(world),
            neighbours=lambda: [Neighbour(2, grounded, (0.0, 0.0, 0.0))],
        )

        async def mission(f: Flight, stop: asyncio.Event) -> None:
            assert await f.fly_path([(grounded[0], grounded[1], ALTITUDE)], stop)

        try:
            await flight.run(mission, asyncio.Event())
        finally:
            await flight.ap.close()
        return server.status(), flight, events


@pytest.mark.sim
def test_a_drone_coming_down_onto_one_on_the_ground_lands_beside_it() -> None:
    status, flight, events = asyncio.run(_come_down_onto_a_grounded_drone())
    [beside] = [e for e in events if e["event"] == "land_beside"]
    assert beside["below"] == [2] and beside["spot"] is not None  # it was over the grounded drone
    assert flight.phase == Phase.LANDED
    assert status["collision_events"] == []
    x, y, _ = status["vehicles"][0]["position"]
    assert math.hypot(x - 2.3, y - 2.0) > 0.8


@pytest.mark.sim
def test_the_drone_with_the_right_of_way_holds_for_one_about_to_cross_its_way() -> None:
    # drone 1 flies west along a corridor; drone 3 comes out of a doorway 0.8 m ahead, still 0.7 m off its line
    here, target = np.array([22.0, 9.6, 1.5]), np.array([15.0, 9.6, 1.5])
    leaving_the_door = Neighbour(3, (21.4, 8.9, 1.5), (0.0, 1.0, 0.0), heading_to=(21.4, 11.0, 1.5))
    standing_in_it = leaving_the_door._replace(velocity=(0.0, 0.0, 0.0), heading_to=None)
    flight = _offline_flight(1, lambda: [standing_in_it])
    assert flight._rival(here, target) is None  # 0.7 m off our line and staying there: carry on
    flight.neighbours = lambda: [leaving_the_door]
    assert flight._rival(here, target) == leaving_the_door  # it will be on our line in half a second: hold


async def _step_up_and_rejoin() -> tuple[Vec3, list[Vec3], list[Vec3]]:
    """Drone 2 flies east along the box's open strip; drone 1 hovers on its line (a neighbour from the test) and
    is gone once drone 2 is half-way up its step aside. From up there the map shows no clear way on (is_clear
    says so above 1.6 m, as a lintel ahead would), so drone 2 takes up its segment where it left it. Returns where
    it left the segment, its refuges and the positions it flew through after the first step aside."""
    config = sim_config(free_port_block(), **{"sim.spawns": [WEST]})
    # a little lower (the step is up), and on a segment of its own (one parked with none is an obstacle instead)
    peer = Neighbour(1, (2.9, 2.0, ALTITUDE - 0.2), (0.0, 0.0, 0.0), heading_to=(2.9, 2.0, ALTITUDE - 0.2))
    left_at: list[Vec3] = []
    refuges: list[Vec3] = []
    track: list[Vec3] = []
    with running_sim(config, load_world("box")):
        autopilot = Autopilot(f"udpin://127.0.0.1:{gcs_port(config.sim, 1)}", config.mission.origin)
        settings = config.agent.model_copy(update={"id": 2, "altitude_m": ALTITUDE, "hover_s": 0.0})

        def log(event: str, **fields) -> None:
            if event == "give_way":
                left_at.append(autopilot.telemetry.position)
                refuges.append(tuple(fields["refuge"]))

        gone: list[bool] = []

        def neighbours() -> list[Neighbour]:
            if left_at and not gone and autopilot.telemetry.position[2] > left_at[0][2] + STEP_ASIDE_M / 2:
                gone.append(True)
            return [] if gone else [peer]

        flight = Flight(
            autopilot,
            settings,
            log,
            separation_m=1.2,
            neighbours=neighbours,
            is_clear=lambda a, b: a[2] < ALTITUDE + 0.1 and b[2] < ALTITUDE + STEP_ASIDE_M + 0.1,
        )

        async def mission(f: Flight, stop: asyncio.Event) -> None:
            async def record() -> None:
                while True:
                    if left_at:
                        track.append(autopilot.telemetry.position)
                    await asyncio.sleep(0.05)

            recorder = asyncio.create_task(record())
            try:
                assert await f.fly_path([(EAST[0], EAST[1], ALTITUDE)], stop)
            finally:
                recorder.cancel()

        try:
            await flight.run(mission, asyncio.Event())
        finally:
            await autopilot.close()
    assert left_at, "drone 2 never gave way: the scenario did not happen"
    return left_at[0], refuges, track


@pytest.mark.sim
def test_a_drone_that_stepped_up_flies_back_down_before_going_on_along_its_segment() -> None:
    left_at, refuges, track = asyncio.run(_step_up_and_rejoin())
    assert refuges[0][2] > left_at[2] + STEP_ASIDE_M / 2  # it stepped up
    highest = max(p[2] for p in track)
    assert highest > left_at[2] + STEP_ASIDE_M / 2  # and was half-way up when the way cleared
    # from the top of its step, going on at once, it flew a diagonal after the carrot: 0.3 m further on it was
    # still 0.23 m above the segment (0.08 m when it flies the step back first)
    top = max(range(len(track)), key=lambda i: track[i][2])
    on = [p for p in track[top:] if p[0] > track[top][0] + 0.3]
    assert on, "it never went on"
    assert max(p[2] for p in on) < left_at[2] + 0.15
    assert math.dist(track[-1][:2], EAST[:2]) < 0.6


@pytest.mark.sim
def test_the_drone_with_the_right_of_way_passes_one_waiting_at_its_refuge_unless_it_would_touch_it() -> None:
    # drone 2 stepped aside for drone 1 and waits at its refuge; drone 1's way round it passes 0.56 m off. Held
    # for as a drone in its way (0.6 m), each waited for the other for 190 s (box, uncoordinated)
    here, target = np.array([1.0, 2.0, 1.5]), np.array([3.0, 2.0, 1.5])
    waiting = Neighbour(2, (2.0, 2.56, 1.5), (0.0, 0.0, 0.0), heading_to=(2.0, 2.56, 1.5))
    flight = _offline_flight(1, lambda: [waiting])
    assert flight._rival(here, target) is None  # 0.56 m off our line, waiting for us: pass it
    in_it = waiting._replace(position=(2.0, 2.3, 1.5), heading_to=(2.0, 2.3, 1.5))
    flight.neighbours = lambda: [in_it]
    assert flight._rival(here, target) == in_it  # 0.3 m off: we would touch it, hold
    on_its_way = waiting._replace(heading_to=(2.0, 5.0, 1.5))
    flight.neighbours = lambda: [on_its_way]
    assert flight._rival(here, target) == on_its_way  # about to move (its way ahead): hold, as before


def _offline_flight(agent_id: int, neighbours: Callable[[], list[Neighbour]]) -> Flight:
    """A Flight of drone `agent_id` whose autopilot is never connected: for its separation rules alone."""
    config = sim_config(free_port_block())
    settings = config.agent.model_copy(update={"id": agent_id})
    autopilot = Autopilot("udpin://127.0.0.1:9", config.mission.origin)
    return Flight(autopilot, settings, lambda *a, **kw: None, separation_m=1.2, neighbours=neighbours)


@pytest.mark.sim
def test_drones_closing_head_on_at_speed_give_way_before_they_are_within_the_separation() -> None:
    # gen:9, 3 drones: drone 1 north along a corridor at 1.7 m/s, drone 3 south at 1.4 m/s, 3.8 m apart: a
    # third of a second after they came within 1.2 m they touched. Now both act while still 3.8 m apart.
    north, south = np.array([5.5, 12.65, 1.3]), np.array([5.21, 16.41, 1.3])
    towards_1 = Neighbour(1, (5.5, 12.65, 1.3), (0.0, 1.7, 0.0), heading_to=(5.5, 25.0, 1.3))
    towards_3 = Neighbour(3, (5.21, 16.41, 1.3), (0.3, -1.4, 0.0), heading_to=(5.5, 7.3, 1.3))
    yielder = _offline_flight(3, lambda: [towards_1])
    yielder.ap.telemetry.velocity = towards_3.velocity
    assert yielder._rival(south, np.array(towards_3.heading_to)) == towards_1  # gives way
    holder = _offline_flight(1, lambda: [towards_3])
    holder.ap.telemetry.velocity = towards_1.velocity
    assert holder._rival(north, np.array(towards_1.heading_to)) == towards_3  # in its way: holds
    # standing still, 3.8 m apart is no conflict yet; nor is a drone flying by 1.5 m to the side
    yielder.ap.telemetry.velocity = (0.0, 0.0, 0.0)
    yielder.neighbours = lambda: [towards_1._replace(velocity=(0.0, 0.0, 0.0))]
    assert yielder._rival(south, np.array(towards_3.heading_to)) is None
    yielder.neighbours = lambda: [towards_1._replace(position=(3.7, 12.65, 1.3))]
    assert yielder._rival(south, np.array(towards_3.heading_to)) is None


@pytest.mark.sim
def test_a_drone_given_way_to_from_beyond_the_separation_is_past_only_once_it_will_not_come_within_it() -> None:
    # Given way to because it closed fast from 2.5 m, and at once found past because it was farther than the
    # separation: the yield ended and began again every few milliseconds (gen:15), the agent's loop spinning.
    here = (5.21, 16.41, 1.3)
    closing = Neighbour(1, (5.21, 13.9, 1.3), (0.0, 1.7, 0.0), heading_to=(5.21, 25.0, 1.3))
    yielder = _offline_flight(3, lambda: [closing])
    yielder.ap.telemetry.position = here
    yielder.ap.telemetry.velocity = (0.0, 0.0, 0.0)  # hovering where it stepped aside to
    assert yielder._rival(np.array(here), np.array(here)) == closing
    assert not yielder._past(closing)
    assert yielder._past(closing._replace(velocity=(0.0, 0.0, 0.0)))  # 2.5 m away, still
    assert yielder._past(closing._replace(position=(5.21, 18.5, 1.3)))  # by us, 2.1 m on and moving away
    assert not yielder._past(closing._replace(position=(5.21, 17.2, 1.3)))  # by us, but 0.8 m away


def test_a_yield_to_a_drone_that_parked_ends_once_it_has_stayed_parked() -> None:
    # It will not come past: waiting for it to be past lasted until the yield timed out (MAX_YIELD_S); ended as soon
    # as it parked, a yield to a drone between two paths began again 0.2 s later, four times in a row.
    landing = Neighbour(1, (0.8, 0.0, 1.0), (0.0, 0.0, -0.7))
    settings = load_config().agent.model_copy(update={"id": 2})
    autopilot = FakeAutopilot(in_air=True)
    flight = Flight(autopilot, settings, lambda *a, **kw: None, separation_m=1.2, neighbours=lambda: [landing])  # type: ignore[arg-type]

    async def yield_to_it() -> tuple[bool, float]:
        started = time.monotonic()
        done = await flight._step_aside(1, asyncio.Event(), None)
        return done, time.monotonic() - started

    done, waited = asyncio.run(yield_to_it())
    assert done and PARKED_FOR_S <= waited < MAX_YIELD_S
