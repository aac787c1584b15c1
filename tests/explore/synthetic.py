"""Occupancy grids built in numpy for the explore tests and the planner benchmark."""

from __future__ import annotations

import numpy as np

from swarm.config import Vec3
from swarm.explore.grid import OccupancyGrid


def empty_grid(size_m: Vec3, resolution: float = 0.2, origin: Vec3 = (0.0, 0.0, 0.0)) -> OccupancyGrid:
    shape = tuple(int(round(s / resolution)) for s in size_m)
    return OccupancyGrid(np.array(origin, dtype=float), resolution, np.zeros(shape, dtype=bool))


def cells_in_box(grid: OccupancyGrid, lo: Vec3, hi: Vec3) -> tuple[slice, slice, slice]:
    """Index slices of the cells whose centre lies in the box [lo, hi]."""
    first = np.ceil((np.asarray(lo) - grid.origin) / grid.resolution - 0.5 - 1e-9).astype(int)
    last = np.floor((np.asarray(hi) - grid.origin) / grid.resolution - 0.5 + 1e-9).astype(int)
    first = np.clip(first, 0, grid.shape)
    last = np.clip(last + 1, 0, grid.shape)
    i, j, k = (slice(int(a), int(b)) for a, b in zip(first, last))
    return i, j, k


def fill(grid: OccupancyGrid, lo: Vec3, hi: Vec3, value: bool = True) -> OccupancyGrid:
    grid.occupied[cells_in_box(grid, lo, hi)] = value
    return grid


def room_with_wall(door_open: bool = True) -> OccupancyGrid:
    """8 x 6 x 3 m, a wall across x = 4 m with a 1.2 m wide, 2 m high door at y 2.4..3.6 m."""
    grid = empty_grid((8.0, 6.0, 3.0))
    fill(grid, (4.0, 0.0, 0.0), (4.19, 6.0, 3.0))
    if door_open:
        fill(grid, (4.0, 2.4, 0.0), (4.19, 3.6, 2.0), value=False)
    return grid


def office_grid(resolution: float = 0.2) -> OccupancyGrid:
    """30 x 20 x 3 m office: floor, ceiling, outer walls, a corridor along x at y 8.5..11.5 m and ten
    6 m wide rooms on either side, each with a 1 m wide, 2.1 m high door onto the corridor."""
    grid = empty_grid((30.0, 20.0, 3.0), resolution)
    wall = resolution * 0.99
    fill(grid, (0, 0, 0), (30, 20, wall))
    fill(grid, (0, 0, 3 - wall), (30, 20, 3))
    fill(grid, (0, 0, 0), (wall, 20, 3))
    fill(grid, (30 - wall, 0, 0), (30, 20, 3))
    fill(grid, (0, 0, 0), (30, wall, 3))
    fill(grid, (0, 20 - wall, 0), (30, 20, 3))
    for y in (8.5, 11.5):
        fill(grid, (0, y, 0), (30, y + wall, 3))
    for x in (6.0, 12.0, 18.0, 24.0):
        fill(grid, (x, 0, 0), (x + wall, 8.5, 3))
        fill(grid, (x, 11.5, 0), (x + wall, 20, 3))
    for room_x in (0.0, 6.0, 12.0, 18.0, 24.0):
        fill(grid, (room_x + 1.0, 8.5, wall), (room_x + 2.0, 8.5 + wall, 2.1), value=False)
        fill(grid, (room_x + 4.0, 11.5, wall), (room_x + 5.0, 11.5 + wall, 2.1), value=False)
    return grid


def clearance(grid: OccupancyGrid, points: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest occupied cell cube (brute force; small grids only)."""
    centres = grid.centre_of(np.argwhere(grid.occupied))
    gaps = np.maximum(np.abs(points[:, None, :] - centres[None, :, :]) - grid.resolution / 2, 0.0)
    return np.linalg.norm(gaps, axis=2).min(axis=1)


def densify(path: list[Vec3], step: float) -> np.ndarray:
    """Points along `path` no more than `step` apart, both ends of every segment included."""
    points = [np.asarray(path[0], dtype=float)[None, :]]
    for a, b in zip(path[:-1], path[1:]):
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
        points.append(a + np.linspace(0, 1, n + 1)[1:, None] * (b - a))
    return np.concatenate(points)


# State grids (UNKNOWN / FREE / OCCUPIED, as FusedMap.occupancy_grid exports them) for the frontier tests.


def state_grid(size_m: Vec3, value: int, resolution: float = 0.2) -> np.ndarray:
    shape = tuple(int(round(s / resolution)) for s in size_m)
    return np.full(shape, value, dtype=np.uint8)


def set_states(states: np.ndarray, lo: Vec3, hi: Vec3, value: int, resolution: float = 0.2) -> np.ndarray:
    """Give `value` to the cells whose centre lies in the box [lo, hi] (grid origin at 0)."""
    shaped = OccupancyGrid(np.zeros(3), resolution, np.broadcast_to(False, states.shape))
    states[cells_in_box(shaped, lo, hi)] = value
    return states


def room_states(known_to_x: float = 4.0, wall_x: float | None = None, door: bool = False) -> np.ndarray:
    """The 8 x 6 x 3 m room of `room_with_wall` as a state grid: one-cell floor, ceiling and walls, free inside,
    and everything at x >= `known_to_x` unknown (walls included). `wall_x`: a one-cell wall across x there,
    with `door` a 1.2 m wide, 2 m high opening at y 2.4..3.6 m."""
    from swarm.patches.fused import FREE, OCCUPIED, UNKNOWN

    states = state_grid((8.0, 6.0, 3.0), OCCUPIED)
    set_states(states, (0.2, 0.2, 0.2), (7.8, 5.8, 2.8), FREE)
    if wall_x is not None:
        set_states(states, (wall_x, 0.0, 0.0), (wall_x + 0.19, 6.0, 3.0), OCCUPIED)
        if door:
            set_states(states, (wall_x, 2.4, 0.2), (wall_x + 0.19, 3.6, 2.0), FREE)
    set_states(states, (known_to_x, 0.0, 0.0), (8.0, 6.0, 3.0), UNKNOWN)
    return states


def warehouse_states(known_to_x: float = 20.0, speckle: float = 0.01, seed: int = 0) -> np.ndarray:
    """40 x 25 x 6.4 m warehouse at 0.2 m, half explored: floor, outer walls and a roof at 6 m; four rows of
    10 m x 1 m x 4 m racks along x; known up to `known_to_x` except the racks' far sides above 2 m (shadows)
    and a `speckle` share of free cells left unknown (thin spots of a real TSDF map)."""
    from swarm.patches.fused import FREE, OCCUPIED, UNKNOWN

    states = state_grid((40.0, 25.0, 6.4), UNKNOWN)
    set_states(states, (0.0, 0.0, 0.0), (40.0, 25.0, 6.2), OCCUPIED)
    set_states(states, (0.2, 0.2, 0.2), (39.8, 24.8, 5.8), FREE)
    for x0 in (3.0, 16.0, 29.0):
        for y0 in (4.0, 9.0, 14.0, 19.0):
            set_states(states, (x0, y0, 0.0), (x0 + 10.0, y0 + 1.0, 4.0), OCCUPIED)
            set_states(states, (x0, y0 + 1.0, 2.0), (x0 + 10.0, y0 + 1.6, 4.0), UNKNOWN)
    rng = np.random.default_rng(seed)
    states[(states == FREE) & (rng.random(states.shape) < speckle)] = UNKNOWN
    set_states(states, (known_to_x, 0.0, 0.0), (40.0, 25.0, 6.4), UNKNOWN)
    return states
