"""Scripted routes keep clear of walls (checked against the mesh itself) and keep same-layer drones apart in time."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.sim.routes import SAFETY_MARGIN_M, TAKEOFF_AND_LANDING_S, scripted_routes
from swarm.sim.worlds import load_world, spawn_points

RADIUS = 0.2
SPEED = 1.5


@pytest.fixture(scope="module")
def office_routes():
    world = load_world("office")
    spawns = spawn_points(world, None, 7, 1.5)  # more drones than layers fit under the 3 m ceiling
    lo, hi = world.bounds
    return world, spawns, scripted_routes(world, spawns, lo, hi, RADIUS, SPEED)


def _sample(a: np.ndarray, b: np.ndarray, step: float = 0.05) -> np.ndarray:
    n = max(2, int(np.ceil(np.linalg.norm(b - a) / step)) + 1)
    return a + (b - a) * np.linspace(0, 1, n)[:, None]


def test_every_leg_keeps_clear_of_the_mesh(office_routes) -> None:
    world, spawns, routes = office_routes
    for route in routes:
        home = np.array(spawns[route.drone_id - 1])
        points = [home + (0, 0, route.altitude_m), *map(np.array, route.waypoints)]
        samples = np.concatenate([_sample(a, b) for a, b in zip(points, points[1:])])
        clearance = world.distance(samples)
        # The grid is checked at cell centres; a point between centres may be up to half a cell diagonal nearer.
        assert clearance.min() > RADIUS + SAFETY_MARGIN_M - 0.1 * np.sqrt(3), (route.drone_id, clearance.min())
        assert not world.is_inside_solid(samples).any()


def test_routes_tour_a_sector_and_end_above_home(office_routes) -> None:
    _, spawns, routes = office_routes
    assert [r.drone_id for r in routes] == [1, 2, 3, 4, 5, 6, 7]
    for route in routes:
        home = np.array(spawns[route.drone_id - 1])
        assert route.length_m > 2.0
        assert np.allclose(route.waypoints[-1], home + (0, 0, route.altitude_m), atol=0.01)
        assert all(abs(w[2] - home[2] - route.altitude_m) < 1e-9 for w in route.waypoints)


def test_drones_sharing_a_layer_are_never_airborne_together(office_routes) -> None:
    _, _, routes = office_routes
    by_layer: dict[float, list] = {}
    for route in routes:
        by_layer.setdefault(route.altitude_m, []).append(route)
    layers = sorted(by_layer)
    assert len(layers) == 5  # 0.75 .. 2.55 m: the ones that fit under the 3 m ceiling with clearance
    assert max(layers) + RADIUS + SAFETY_MARGIN_M <= 3.0
    assert min(b - a for a, b in zip(layers, layers[1:])) > 2 * RADIUS
    assert any(len(shared) > 1 for shared in by_layer.values())
    for shared in by_layer.values():
        for earlier, later in zip(shared, shared[1:]):
            earlier_done = earlier.start_delay_s + TAKEOFF_AND_LANDING_S + earlier.length_m / SPEED
            assert later.start_delay_s >= earlier_done
