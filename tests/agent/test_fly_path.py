"""Path following against the simulator through real MAVSDK: a new path starts where the drone is."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from swarm.agent.autopilot import Autopilot
from swarm.agent.flight import CORNER_CUT_M, GENTLE_TURN_DEG, Flight, distance_to_segment
from swarm.config import Vec3, gcs_port
from swarm.sim.worlds import load_world
from tests.agent.mesh_clearance import clear_in
from tests.sim.support import free_port_block, running_sim, sim_config

pytestmark = pytest.mark.timeout(120)

HOME = (1.0, 1.5, 0.0)  # the box's open strip south of its wall stub
ALTITUDE = 1.5


async def _redirected_mid_segment() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
    """Fly east, interrupt the path at full speed, then fly a new path north-west from where the drone is;
    returns where the new path started, its goal, the positions flown and the setpoints sent along it, and
    the simulator's status."""
    config = sim_config(free_port_block(), **{"mission.drones": 1, "sim.spawns": [HOME]})
    with running_sim(config, load_world("box")) as server:
        autopilot = Autopilot(f"udpin://127.0.0.1:{gcs_port(config.sim, 1)}", config.mission.origin)
        settings = config.agent.model_copy(update={"id": 1, "altitude_m": ALTITUDE, "hover_s": 0.0})
        flight = Flight(autopilot, settings, lambda *a, **kw: None)
        flown: list[np.ndarray] = []
        setpoints: list[np.ndarray] = []
        start: list[np.ndarray] = []
        goal = np.zeros(3)

        async def mission(flight: Flight, stop: asyncio.Event) -> None:
            interrupt = asyncio.Event()
            asyncio.get_running_loop().call_later(3.0, interrupt.set)
            assert not await flight.fly_path([(7.0, 1.5, ALTITUDE)], stop, interrupt=interrupt)
            here = np.array(flight.ap.telemetry.position)
            start.append(here)
            goal[:] = (1.0, 5.0, ALTITUDE)  # north-west: passes the stub's end (x 4.0-4.15, y >= 3) well clear

            async def record() -> None:
                while True:
                    flown.append(np.array(flight.ap.telemetry.position))
                    if flight.setpoint is not None:
                        setpoints.append(np.array(flight.setpoint))
                    await asyncio.sleep(0.05)

            recorder = asyncio.create_task(record())
            try:
                assert await flight.fly_path([tuple(goal)], stop)
            finally:
                recorder.cancel()

        stop = asyncio.Event()
        try:
            await flight.run(mission, stop)
        finally:
            await flight.ap.close()
        return start[0], goal, np.array(flown), np.array(setpoints), server.status()


@pytest.mark.sim
def test_a_new_path_starts_from_the_drone_not_from_the_interrupted_paths_setpoint() -> None:
    start, goal, flown, setpoints, status = asyncio.run(_redirected_mid_segment())
    assert status["collisions"] == 0
    assert np.linalg.norm(flown[-1] - goal) < 0.35
    # The drone was moving east at cruise speed, its old setpoint up to a metre ahead of it: the new path's
    # setpoints must lie on the planned segment itself, not on one from that stale setpoint
    assert len(setpoints) > 20
    assert max(distance_to_segment(p, start, goal) for p in setpoints) < 0.05
    # ... and the drone flies it, carried off only by its momentum (0.42 m at the 1.4 m/s of a 1.5 m lead: it goes
    # on along the interrupted path's segment, which the map showed clear)
    assert max(distance_to_segment(p, start, goal) for p in flown) < 0.5


async def _replanned_straight_on() -> tuple[list[float], float]:
    """Fly east, and 2 s on (at full speed) replace the path with one that goes on east-north-east, as a drone
    given a new target ahead does; returns the drone's horizontal speeds over the second after the change (the
    new path is long enough that its end is not in sight yet), and the cruise speed."""
    config = sim_config(free_port_block(), **{"mission.drones": 1, "sim.spawns": [HOME]})
    with running_sim(config, load_world("box")):
        autopilot = Autopilot(f"udpin://127.0.0.1:{gcs_port(config.sim, 1)}", config.mission.origin)
        settings = config.agent.model_copy(update={"id": 1, "altitude_m": ALTITUDE, "hover_s": 0.0})
        flight = Flight(autopilot, settings, lambda *a, **kw: None)
        speeds: list[float] = []

        async def mission(flight: Flight, stop: asyncio.Event) -> None:
            interrupt = asyncio.Event()
            asyncio.get_running_loop().call_later(2.0, interrupt.set)
            assert not await flight.fly_path([(5.2, 1.5, ALTITUDE)], stop, interrupt=interrupt)

            async def record() -> None:
                for _ in range(20):
                    vx, vy, _ = flight.ap.telemetry.velocity
                    speeds.append(float(np.hypot(vx, vy)))
                    await asyncio.sleep(0.05)

            recorder = asyncio.create_task(record())
            assert await flight.fly_path([(7.0, 2.6, ALTITUDE)], stop)  # 0.3 m clear of the pillar
            await recorder

        try:
            await flight.run(mission, asyncio.Event())
        finally:
            await flight.ap.close()
        return speeds, settings.cruise_speed_m_s


@pytest.mark.sim
def test_a_new_path_straight_on_does_not_brake_the_drone() -> None:
    speeds, cruise = asyncio.run(_replanned_straight_on())
    assert speeds[0] > 0.6 * cruise  # it was flying
    # with the new carrot at the drone, the drone braked to 0.34 m/s before going on
    assert min(speeds) > 0.6 * cruise


CORNERED = [(2.5, 1.5, ALTITUDE), (3.5, 2.2, ALTITUDE), (3.5, 4.5, ALTITUDE)]  # turns of 35 and 55 degrees


async def _cornered(room: str, route: list[Vec3] | None = None) -> tuple[float, np.ndarray, np.ndarray, dict]:
    """Fly CORNERED from above HOME (the box's open strip, west of the wall stub's end at (4.0-4.15, 3.0)) with
    a map that shows the corners in open space (`room` "open": 0.45 m from every surface), with one that shows
    no open space ("tight": no roomy cells, straight ways checked 0.5 m clear) or without a map ("none");
    returns the time taken, the positions flown (every 50 ms), the path flown and the simulator's status."""
    world = load_world("box")
    config = sim_config(free_port_block(), **{"mission.drones": 1, "sim.spawns": [HOME]})
    with running_sim(config, world) as server:
        autopilot = Autopilot(f"udpin://127.0.0.1:{gcs_port(config.sim, 1)}", config.mission.origin)
        settings = config.agent.model_copy(update={"id": 1, "altitude_m": ALTITUDE, "hover_s": 0.0})
        roomy = clear_in(world, margin=0.45) if room == "open" else None
        is_clear = clear_in(world) if room != "none" else None
        flight = Flight(autopilot, settings, lambda *a, **kw: None, is_clear=is_clear, is_roomy=roomy)
        flown: list[np.ndarray] = []
        took: list[float] = []

        async def mission(flight: Flight, stop: asyncio.Event) -> None:
            async def record() -> None:
                while True:
                    flown.append(np.array(flight.ap.telemetry.position))
                    await asyncio.sleep(0.05)

            recorder = asyncio.create_task(record())
            started = asyncio.get_running_loop().time()
            try:
                assert await flight.fly_path(route or CORNERED, stop)
            finally:
                recorder.cancel()
            took.append(asyncio.get_running_loop().time() - started)

        try:
            await flight.run(mission, asyncio.Event())
        finally:
            await flight.ap.close()
        path = np.array([(HOME[0], HOME[1], ALTITUDE), *(route or CORNERED)])
        return took[0], np.array(flown), path, server.status()


def _off_the_path(points: np.ndarray, path: np.ndarray) -> float:
    """Horizontally (the path is level; the take-off's last centimetres of climb are not a corner)."""
    level = points * [1.0, 1.0, 0.0] + [0.0, 0.0, ALTITUDE]
    return max(min(distance_to_segment(p, a, b) for a, b in zip(path, path[1:])) for p in level)


@pytest.mark.sim
def test_a_drone_rounds_open_corners_inside_them_tight_ones_near_them_and_without_a_map_flies_the_path() -> None:
    open_time, open_flown, path, open_status = asyncio.run(_cornered("open"))
    tight_time, tight_flown, _, tight_status = asyncio.run(_cornered("tight"))
    kept_time, kept_flown, _, kept_status = asyncio.run(_cornered("none"))
    assert open_status["collisions"] == tight_status["collisions"] == kept_status["collisions"] == 0
    # measured: 5.63 s, 6.53 s and 7.95 s; 0.179 m, 0.068 m and 0.048 m off the path at most
    assert _off_the_path(kept_flown, path) < 0.1  # it came to each corner before turning
    assert _off_the_path(open_flown, path) > 0.12  # it turned inside them
    assert _off_the_path(tight_flown, path) < CORNER_CUT_M  # it turned within CORNER_CUT_M of each corner
    assert open_time < 0.85 * kept_time, (open_time, kept_time)
    assert tight_time < 0.9 * kept_time, (tight_time, kept_time)


def _zigzag(turn_deg: float, legs: int = 6, leg_m: float = 0.7) -> list[Vec3]:
    """East from above HOME along the box's open strip, turning `turn_deg` left and right in turn."""
    x, y, route = HOME[0], HOME[1], []
    for i in range(legs):
        heading = np.radians(turn_deg / 2 if i % 2 == 0 else -turn_deg / 2)
        x, y = x + leg_m * np.cos(heading), y + leg_m * np.sin(heading)
        route.append((float(x), float(y), ALTITUDE))
    return route


@pytest.mark.sim
def test_a_drone_keeps_its_speed_through_gentle_turns_where_its_map_shows_the_way_clear() -> None:
    """A planned path bends every 0.5-1 m round what it keeps clear of; at turns of GENTLE_TURN_DEG or less the
    carrot runs on (and keeps its lead) where the straight way to it is clear, even with no open space mapped."""
    zigzag = _zigzag(GENTLE_TURN_DEG - 10.0)
    mapped_time, mapped_flown, path, mapped_status = asyncio.run(_cornered("tight", zigzag))
    kept_time, kept_flown, _, kept_status = asyncio.run(_cornered("none", zigzag))
    assert mapped_status["collisions"] == kept_status["collisions"] == 0
    # measured: 4.33 s against 8.68 s without a map (6.74 s with the map before gentle turns were cut); 0.076 m
    # and 0.035 m off the path at most
    assert mapped_time < 0.75 * kept_time, (mapped_time, kept_time)
    assert _off_the_path(mapped_flown, path) < 0.15
    assert _off_the_path(kept_flown, path) < 0.1


async def _turned_back_round_a_corner() -> tuple[np.ndarray, np.ndarray, dict]:
    """Fly east at speed, interrupt the path, then fly a new one that turns back a little (0.1 m west of where the
    drone was) and then north, on a map that shows no straight way from the drone clear (the drone is in a
    cell that is not safe, next to a wall, as a momentum carries it). Returns the new path (from where the drone
    was), the positions flown along it and the simulator's status."""
    config = sim_config(free_port_block(), **{"mission.drones": 1, "sim.spawns": [HOME]})
    with running_sim(config, load_world("box")) as server:
        autopilot = Autopilot(f"udpin://127.0.0.1:{gcs_port(config.sim, 1)}", config.mission.origin)
        settings = config.agent.model_copy(update={"id": 1, "altitude_m": ALTITUDE, "hover_s": 0.0})
        flight = Flight(autopilot, settings, lambda *a, **kw: None, is_clear=lambda a, b: False)
        flown: list[np.ndarray] = []
        path: list[Vec3] = []

        async def mission(flight: Flight, stop: asyncio.Event) -> None:
            interrupt = asyncio.Event()
            asyncio.get_running_loop().call_later(2.0, interrupt.set)
            assert not await flight.fly_path([(5.2, HOME[1], ALTITUDE)], stop, interrupt=interrupt)
            x, y, _ = flight.ap.telemetry.position
            path.extend([(x, y, ALTITUDE), (x - 0.1, y, ALTITUDE), (x - 0.1, y + 1.2, ALTITUDE)])

            async def record() -> None:
                while True:
                    flown.append(np.array(flight.ap.telemetry.position))
                    await asyncio.sleep(0.05)

            recorder = asyncio.create_task(record())
            try:
                assert await flight.fly_path(path[1:], stop)
            finally:
                recorder.cancel()

        try:
            await flight.run(mission, asyncio.Event())
        finally:
            await flight.ap.close()
        return np.array(path), np.array(flown), server.status()


@pytest.mark.sim
def test_a_drone_carried_past_a_corner_by_its_momentum_comes_back_to_it_before_turning() -> None:
    # gen:1, 3 drones: a drone carried 0.3 m beside a door's jamb turned back, and at the moment it was at rest
    # the carrot ran on along the next segment: the drone flew a chord from there, onto the jamb
    path, flown, status = asyncio.run(_turned_back_round_a_corner())
    assert status["collisions"] == 0
    farthest = max(float(p[0]) for p in flown)
    assert farthest - path[1][0] > 0.3  # its momentum carried it on past the corner
    assert np.linalg.norm(flown[-1][:2] - path[2][:2]) < 0.35  # and it got there
    # back along the way it came, then round the corner, not on a chord from where it turned back (measured:
    # carried 0.52-0.54 m past, then 0.026 m off that way at most; 0.27 m when the carrot ran on at rest)
    way = np.array([(farthest, path[1][1], ALTITUDE), path[1], path[2]])
    assert _off_the_path(flown, way) < 0.15, _off_the_path(flown, way)
