"""Collision events counted by the simulator, stepped with a fake clock (no sockets)."""

import math

import numpy as np
import pytest

from swarm.config import load_config
from swarm.errors import WorldError
from swarm.sim.autopilot import ACCEPTED, Setpoint
from swarm.sim.px4 import FlightMode
from swarm.sim.server import SimServer
from swarm.sim.worlds import World

DT = 0.02


class Flight:
    """A SimServer without sockets, stepped by hand; offboard targets are re-sent every step."""

    def __init__(self, world: World, spawns: list[tuple[float, float, float]]) -> None:
        config = load_config(overrides={"mission.world": world.name, "sim.spawns": [list(s) for s in spawns]})
        self.now = 0.0
        self.server = SimServer(config, world, start_time=self.now)
        self.targets: dict[int, np.ndarray] = {}

    def go(self, vid: int, target: tuple[float, float, float]) -> None:
        ap = self.server.vehicles[vid].autopilot
        self.targets[vid] = np.array(target, dtype=float)
        self._send(vid)
        if not ap.armed:
            assert ap.arm(self.now) == ACCEPTED
        assert ap.set_mode(FlightMode.OFFBOARD, self.now) == ACCEPTED

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds / DT)):
            self.now += DT
            for vid in self.targets:
                self._send(vid)
            self.server.step(DT, self.now)

    def _send(self, vid: int) -> None:
        sp = Setpoint(self.targets[vid].copy(), np.full(3, np.nan))
        self.server.vehicles[vid].autopilot.set_setpoint(sp, self.now)

    @property
    def status(self) -> dict:
        return self.server.status()


def test_flying_through_a_wall_counts_one_event_per_contact(box_world: World) -> None:
    flight = Flight(box_world, [(2.0, 4.5, 0.0), (2.0, 1.5, 0.0)])
    flight.go(1, (6.0, 4.5, 1.5))  # through the wall stub at x = 4.0 .. 4.15
    flight.run(6.0)
    status = flight.status
    assert status["collisions"] == 1
    event = status["collision_events"][0]
    assert event["kind"] == "world" and event["vehicles"] == [1]
    assert 3.5 < event["position"][0] < 4.0 and event["t"] > 0
    assert status["vehicles"][0]["position"][0] == pytest.approx(6.0, abs=0.05)  # kept flying, not crashed
    flight.go(1, (2.0, 4.5, 1.5))  # and back: a second contact
    flight.run(6.0)
    status = flight.status
    assert status["collisions"] == 2
    assert [v["collisions"] for v in status["vehicles"]] == [2, 0]


def test_two_vehicles_at_one_point_collide_once(box_world: World) -> None:
    flight = Flight(box_world, [(2.0, 1.5, 0.0), (3.5, 1.5, 0.0)])
    flight.go(1, (2.75, 1.5, 1.5))
    flight.go(2, (2.75, 1.5, 1.5))
    flight.run(6.0)  # they meet and stay in contact: still one event
    status = flight.status
    assert status["collisions"] == 1
    event = status["collision_events"][0]
    assert event["kind"] == "drone" and event["vehicles"] == [1, 2]
    assert [v["collisions"] for v in status["vehicles"]] == [1, 1]


def test_vehicles_on_the_floor_or_hovering_in_free_space_do_not_collide(box_world: World) -> None:
    flight = Flight(box_world, [(2.0, 3.0, 0.0), (2.0, 1.5, 0.0), (1.0, 4.5, 0.0)])
    flight.server.vehicles[2].autopilot.arm(flight.now)  # armed, idling on the floor
    flight.go(3, (1.0, 4.5, 1.5))  # hovering in the open
    flight.run(5.0)
    status = flight.status
    assert status["collisions"] == 0
    assert status["vehicles"][0]["landed_state"] == "on_ground"
    assert status["vehicles"][2]["landed_state"] == "in_air"


def test_travelled_distance(box_world: World) -> None:
    flight = Flight(box_world, [(2.0, 3.0, 0.0)])
    flight.go(1, (2.0, 3.0, 1.0))
    flight.run(4.0)
    flight.go(1, (3.0, 3.0, 1.0))
    flight.run(4.0)
    assert flight.status["vehicles"][0]["distance_m"] == pytest.approx(2.0, abs=0.1)


def test_a_home_inside_a_wall_is_refused(box_world: World) -> None:
    config = load_config(overrides={"mission.world": "box", "sim.spawns": [[2.0, 3.0, 0.0], [4.07, 4.0, 0.0]]})
    with pytest.raises(WorldError, match="vehicle 2"):
        SimServer(config, box_world)


def test_the_closest_approach_to_the_world_and_to_another_drone_is_measured(box_world: World) -> None:
    # vehicle 1 hovers 0.3 m from the wall stub's end face (y = 3.0): its 0.2 m sphere is 0.1 m from it
    flight = Flight(box_world, [(4.07, 2.7, 0.0), (2.0, 1.5, 0.0), (1.0, 4.5, 0.0)])
    flight.go(1, (4.07, 2.7, 1.5))
    flight.go(2, (4.07, 1.9, 1.5))  # 0.8 m from vehicle 1: the spheres are 0.4 m apart
    flight.run(6.0)
    first, second, grounded = flight.status["vehicles"]
    assert flight.status["collisions"] == 0
    assert first["closest_world_m"] == pytest.approx(0.1, abs=0.01)
    assert first["closest_world_at"][:2] == pytest.approx([4.07, 2.7], abs=0.02)  # the stub is full height
    # never within NEAR_GAP_M of a surface, take-off included
    assert second["closest_world_m"] is None and second["closest_world_at"] is None
    assert first["closest_drone_m"] == pytest.approx(0.4, abs=0.02)
    assert second["closest_drone_m"] == pytest.approx(0.4, abs=0.02)
    assert grounded["closest_world_m"] is None  # it never flew
    # ... but others flew near it: closest when vehicle 2 took off from (2.0, 1.5), 3.16 m away
    assert grounded["closest_drone_m"] == pytest.approx(math.hypot(1.0, 3.0) - 0.4, abs=0.02)
