"""Scripted routes for the flight-only mission: each drone tours its own sector of the mission volume.

This is the stand-in for exploration until the swarm plans its own targets. The routes are planned on the
world's ground-truth occupancy (the simulation harness knows the building; the drones do not), inflated by
the drone radius plus a margin, so a scripted flight never touches a wall.

Sectors are strips across the longer horizontal axis of the mission volume, handed to drones in the order of
their spawn points along that axis so outbound legs do not cross; drones fly at staggered altitudes so that
legs that do cross are vertically separated (0.45 m apart, more than two drone radii). The layers used are those
that fit under the ceiling above the take-off area (three under an office's 3 m ceiling, all eleven in a 6 m
hall); a drone that has to share its layer with an earlier one waits on the ground until that one is expected to
have landed (real deconfliction between drones comes with autonomous exploration). A layer above the doorways
simply yields a tour of the spaces reachable at that height.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from swarm.config import Vec3
from swarm.explore.grid import OccupancyGrid
from swarm.explore.planner import NoPathError, path_length, plan_path
from swarm.sim.worlds import World

PLAN_RESOLUTION_M = 0.2
SAFETY_MARGIN_M = 0.15
ALTITUDES_M = (1.2, 0.75, 1.65, 2.1, 2.55, 3.0, 3.45, 3.9, 4.35, 4.8, 5.25)  # above the home floor, 0.45 m apart
MAX_TOUR_M = 45.0  # per drone, out and back: keeps the scripted mission to about a minute of flight
CANDIDATES_TRIED = 12
TAKEOFF_AND_LANDING_S = 12.0  # generous: climb, settle, descend and disarm
SLACK_FACTOR = 1.4  # carrot following and corners make a route slower than length / cruise speed


@dataclass
class ScriptedRoute:
    drone_id: int
    altitude_m: float
    waypoints: list[Vec3]
    length_m: float
    start_delay_s: float = 0.0


def scripted_routes(
    world: World, spawns: list[Vec3], lo: np.ndarray, hi: np.ndarray, drone_radius_m: float, cruise_speed_m_s: float
) -> list[ScriptedRoute]:
    """One route per spawn (drone ids 1..N in spawn order), each ending above the drone's home."""
    free = clearance_grid(world, lo, hi, PLAN_RESOLUTION_M, drone_radius_m + SAFETY_MARGIN_M)
    axis = 0 if hi[0] - lo[0] >= hi[1] - lo[1] else 1
    order = sorted(range(len(spawns)), key=lambda i: spawns[i][axis])
    edges = np.linspace(lo[axis], hi[axis], len(spawns) + 1)
    layers = _layers_under_ceiling(world, spawns, drone_radius_m)
    routes: list[ScriptedRoute] = []
    for strip, index in enumerate(order):
        altitude = layers[index % len(layers)]
        home = np.array(spawns[index], float)
        airborne = (float(home[0]), float(home[1]), float(home[2] + altitude))
        sector = (edges[strip], edges[strip + 1])
        tour = _sector_tour(free, airborne, axis, sector)
        waypoints = tour[1:]  # the first point is where take-off leaves the drone
        routes.append(ScriptedRoute(index + 1, altitude, waypoints, path_length(tour)))
    routes.sort(key=lambda r: r.drone_id)
    _stagger_shared_layers(routes, cruise_speed_m_s)
    return routes


def _layers_under_ceiling(world: World, spawns: list[Vec3], drone_radius_m: float) -> tuple[float, ...]:
    homes = np.array(spawns, float)
    headroom = float(np.min(world.ceiling_above(homes + (0.0, 0.0, 0.1)) - homes[:, 2]))
    fits = tuple(a for a in ALTITUDES_M if a + drone_radius_m + SAFETY_MARGIN_M <= headroom)
    return fits or ALTITUDES_M[:1]


def _stagger_shared_layers(routes: list[ScriptedRoute], cruise_speed_m_s: float) -> None:
    layer_free_at: dict[float, float] = {}
    for route in routes:
        route.start_delay_s = layer_free_at.get(route.altitude_m, 0.0)
        flight_s = TAKEOFF_AND_LANDING_S + SLACK_FACTOR * route.length_m / cruise_speed_m_s
        layer_free_at[route.altitude_m] = route.start_delay_s + flight_s


def clearance_grid(world: World, lo: np.ndarray, hi: np.ndarray, resolution: float, clearance: float) -> OccupancyGrid:
    """Cells whose centre is inside a solid or nearer than `clearance` to a surface are blocked.

    Built from the exact distance to the mesh rather than by inflating a voxelised occupancy, which would
    count the half-diagonal of a cell twice and close doorways a drone fits through.
    """
    shape = np.maximum(1, np.floor((np.asarray(hi) - lo) / resolution).astype(int))
    axes = [lo[i] + (np.arange(shape[i]) + 0.5) * resolution for i in range(3)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    blocked = (world.distance(centres) < clearance) | world.is_inside_solid(centres)
    return OccupancyGrid(np.asarray(lo, float), resolution, blocked.reshape(tuple(shape)))


def _sector_tour(free: OccupancyGrid, airborne: Vec3, axis: int, sector: tuple[float, float]) -> list[Vec3]:
    """Out to the farthest reachable point of the sector (within MAX_TOUR_M there and back), then home."""
    z = airborne[2]
    z_limits = (z, z)  # exactly the one layer of cells that contains the flight altitude
    layer = free.index_of((airborne[0], airborne[1], z))
    if layer is None:
        return [airborne]
    # Only cells connected to the take-off point in this layer (8-connected, as the planner moves) are candidates.
    labels, _ = ndimage.label(~free.occupied[:, :, layer[2]], structure=np.ones((3, 3)))
    if labels[layer[0], layer[1]] == 0:
        return [airborne]
    xs, ys = np.nonzero(labels == labels[layer[0], layer[1]])
    centres = free.origin[:2] + (np.stack([xs, ys], axis=1) + 0.5) * free.resolution
    inside = (centres[:, axis] >= sector[0]) & (centres[:, axis] < sector[1])
    centres = centres[inside]
    if len(centres) == 0:
        return [airborne]
    distance = np.linalg.norm(centres - np.array(airborne[:2]), axis=1)
    best: list[Vec3] | None = None
    # Farthest first, but only as far as half the tour budget allows as the crow flies.
    candidates = centres[np.argsort(-np.where(distance <= MAX_TOUR_M / 2, distance, -1.0))]
    for cx, cy in candidates[:CANDIDATES_TRIED]:
        goal = (float(cx), float(cy), z)
        try:
            out = plan_path(free, airborne, goal, z_limits=z_limits)
            back = plan_path(free, goal, airborne, z_limits=z_limits)
        except NoPathError:
            continue
        # Planning is in one layer of cells; fly it at the drone's own altitude, not at the cells' centres.
        tour = [(x, y, z) for x, y, _ in out + back[1:]]
        if path_length(tour) <= MAX_TOUR_M:
            return tour
        if best is None or path_length(tour) < path_length(best):
            best = tour
    return best if best is not None else [airborne]
