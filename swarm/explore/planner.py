"""Collision-free paths on an inflated occupancy grid: A* over free cells, then line-of-sight shortcutting.

The grid given to `plan_path` must already be inflated by the drone's radius (`OccupancyGrid.inflate`): the
planner treats a point as safe exactly when its cell is free. Replanning after a map update is a new call on
the new grid; `path_is_free` tells whether a path planned earlier is still clear.

When the grid marks its `roomy` cells (free with a wider clearance), paths keep to them where they can: a step
into a free cell that is not roomy costs NOT_ROOMY_COST times its length, and a shortcut may leave the roomy
cells only through cells the A* path itself used. Shortcutting alone pulls every path taut against the
obstacles it turns around, so without this a drone passes each wall end at exactly the minimum clearance, and
any shortfall of the map (a thin wall's end face seen edge-on is reconstructed up to a voxel short) or of the
tracking becomes a contact. Narrow passages (doorways) still use the minimum.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from swarm.config import Vec3
from swarm.explore.grid import OccupancyGrid
from swarm.explore.travel import TravelGraph

# A start or goal in a blocked cell is moved to the nearest free cell centre at most this many cell edges away.
SNAP_RADIUS_CELLS = 2.0
# A step into a free cell that is not roomy costs this many times its length (a metre near an obstacle is worth
# a detour of up to two through open space).
NOT_ROOMY_COST = 3.0
# A search still going after this many expansions starts again with the guide (`plan_path`): most plans end
# sooner than the guide takes to make. Replaying a two-storey generated building's 38 plans on one core: 3.70 s
# plain, 3.41 s so; the four longest 550-690 ms plain, 380-450 ms; three medium ones 56-138 ms, 109-205 ms.
GUIDE_AFTER = 5_000
GUIDE_SLACK_CELLS = 2.0 * math.sqrt(3.0)  # `_guided_heuristic`: a cell to its merged cell's centre, at both ends
# Weighted A*: the heuristic counts this many times over, so a path costs at most this many times the cheapest.
# With an exact (1.0) weight, a 3D search expands every cell whose estimate is under the cheapest cost: round a
# pillar or a wall end, an ellipsoid of near-ties. Replaying 20 plans to frontier viewpoints on a 5-drone hall
# map (48 x 32 m, one idle core): 5.85 s at 1.0 (up to 597 ms a plan), 0.53 s at 1.2 (51 ms at most), 0.93 s at
# 1.5; the paths 2 % longer in all at 1.2 (6 % the worst), as roomy (cost per metre 1.00 either way).
HEURISTIC_WEIGHT = 1.2

_SQRT2 = math.sqrt(2.0)
_SQRT3 = math.sqrt(3.0)
_NEIGHBOUR_STEPS = np.array(
    [(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1) if (dx, dy, dz) != (0, 0, 0)]
)
_STEP_LENGTHS = np.linalg.norm(_NEIGHBOUR_STEPS, axis=1)  # in cells: 1, sqrt(2) or sqrt(3)
_CELL_AND_NEIGHBOURS = np.vstack([np.zeros(3, dtype=int), _NEIGHBOUR_STEPS])


class NoPathError(Exception):
    """No collision-free path; the message says why (outside grid, start/goal blocked, unreachable...)."""


class _GaveUp(NoPathError):
    """The search ran out of expansions before it ended."""


def plan_path(
    grid: OccupancyGrid,
    start: Vec3,
    goal: Vec3,
    *,
    z_limits: tuple[float, float] | None = None,
    max_expansions: int = 2_000_000,
    guide: Callable[[], TravelGraph] | None = None,
) -> list[Vec3]:
    """World waypoints from `start` to `goal` whose every segment crosses only free cells of `grid`.

    A* (weighted: HEURISTIC_WEIGHT) over the 26-connected free cells (Euclidean step cost, NOT_ROOMY_COST times
    that into free cells that are not roomy when the grid marks roomy cells), then greedy line-of-sight
    shortcutting, so a straight corridor gives two points. The first and last points are `start` and `goal`
    themselves when their cells are free; otherwise the nearest free cell centre within SNAP_RADIUS_CELLS cells, or
    NoPathError. `z_limits` (min, max) restricts the search to the grid layers whose centre lies within it;
    limits no wider than a cell, such as (z, z), select the one layer containing their middle. Intermediate
    waypoints are cell centres; a free start or goal keeps its own altitude, which may differ from its
    layer's centre by up to half a cell. `guide`: gives the travel graph of this grid's free cells, made only
    when wanted (most searches end before); a search that has not ended after GUIDE_AFTER expansions starts
    again led by the way through it (`_guided_heuristic`), not by the straight line, which in a building with
    storeys or long walls leads it into every room on the wrong side first (ignored with `z_limits`).
    """
    search_grid = grid if z_limits is None else _restrict_to_layers(grid, z_limits)
    start_point = _free_endpoint(grid, search_grid, start, "start")
    goal_point = _free_endpoint(grid, search_grid, goal, "goal")
    if guide is None or z_limits is not None or max_expansions <= GUIDE_AFTER:
        cells = _astar(search_grid, start_point, goal_point, max_expansions)
    else:
        try:
            cells = _astar(search_grid, start_point, goal_point, GUIDE_AFTER)
        except _GaveUp:  # a long search: worth the guide's own cost (a Dijkstra over the graph, ~40 ms in a hall)
            field = guide().distance_field(goal_point, grid.shape) / grid.resolution
            cells = _astar(search_grid, start_point, goal_point, max_expansions, field)
    waypoints = [start_point, *(search_grid.centre_of(c) for c in cells), goal_point]
    return [_as_vec3(p) for p in _shortcut(_shortcut_grid(search_grid, cells), _drop_repeats(waypoints))]


def plan_path_around(
    grid: OccupancyGrid,
    start: Vec3,
    goal: Vec3,
    avoid: Vec3,
    clearance: float,
    *,
    max_expansions: int = 2_000_000,
    guide: Callable[[], TravelGraph] | None = None,
) -> list[Vec3]:
    """`plan_path` on `grid` with a ball round `avoid` blocked, so the path keeps `clearance` from it (a drone
    parked in the way), or less where the start itself is closer (the ball never swallows the start: the path
    leaves it and goes round). NoPathError when the map has no such way."""
    reach = math.dist(start, avoid) - math.sqrt(3.0) * grid.resolution
    radius = min(clearance, reach)
    if radius <= 0:
        raise NoPathError(f"start {start} is too close to {avoid} to plan round it")
    blocked = grid.with_balls_blocked([avoid], radius)
    return plan_path(blocked, start, goal, max_expansions=max_expansions, guide=guide)


def path_length(path: Sequence[Sequence[float]]) -> float:
    if len(path) < 2:
        return 0.0
    points = np.asarray(path, dtype=float)
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def path_is_free(grid: OccupancyGrid, path: Sequence[Sequence[float]]) -> bool:
    """Every segment of `path` is still collision-free on `grid` (e.g. after a map update)."""
    if len(path) == 1:
        return grid.is_free(path[0])
    return all(grid.segment_is_free(a, b) for a, b in zip(path[:-1], path[1:]))


def _restrict_to_layers(grid: OccupancyGrid, z_limits: tuple[float, float]) -> OccupancyGrid:
    """The slab of `grid` made of the layers allowed by `z_limits` (a contiguous range)."""
    z_min, z_max = sorted(z_limits)
    nz = grid.shape[2]
    tolerance = 1e-6 * grid.resolution
    if z_max - z_min <= grid.resolution + tolerance:
        # (z, z) or (z - res/2, z + res/2): the layer `index_of` gives for z, never two, even when the
        # limits fall exactly on layer centres.
        low = math.floor(((z_min + z_max) / 2 - grid.origin[2]) / grid.resolution)
        high = low + 1
    else:
        centres_z = grid.origin[2] + (np.arange(nz) + 0.5) * grid.resolution
        allowed = np.flatnonzero((centres_z >= z_min - tolerance) & (centres_z <= z_max + tolerance))
        low, high = (int(allowed[0]), int(allowed[-1]) + 1) if len(allowed) else (nz, nz)
    low, high = max(low, 0), min(high, nz)
    if low >= high:
        raise NoPathError(f"z_limits {z_limits} lie outside the grid's altitude range")
    origin = grid.origin + np.array([0.0, 0.0, low * grid.resolution])
    unknown = None if grid.unknown is None else grid.unknown[:, :, low:high]
    roomy = None if grid.roomy is None else grid.roomy[:, :, low:high]
    return OccupancyGrid(origin, grid.resolution, grid.occupied[:, :, low:high], unknown, roomy)


def _shortcut_grid(grid: OccupancyGrid, path_cells: list[np.ndarray]) -> OccupancyGrid:
    """Where shortcuts may go: the roomy cells, the cells of the A* path, and the free cells next to those of
    its cells that are not roomy (every free cell when none is marked roomy). Next to them, because in a narrow
    place every cell costs the same, and A*'s path there is one of many equally short staircases of 45-degree
    steps: string pulling within one cell of it straightens them (on a generated building's mission, half the
    turns over 30 degrees went) and stays in free cells, which keep `clearance_m` from what is mapped. Where the
    path is roomy it stays roomy: there it keeps the wider clearance."""
    if grid.roomy is None:
        return grid
    cells = np.asarray(path_cells)
    allowed = grid.roomy.copy()
    allowed[tuple(cells.T)] = True
    cells = cells[~grid.roomy[tuple(cells.T)]]
    near = (cells[:, None, :] + _CELL_AND_NEIGHBOURS[None]).reshape(-1, 3)
    near = near[np.all((near >= 0) & (near < grid.shape), axis=1)]
    index = tuple(near.T)
    allowed[index] |= ~grid.occupied[index]
    return OccupancyGrid(grid.origin, grid.resolution, ~allowed)


def _free_endpoint(grid: OccupancyGrid, search_grid: OccupancyGrid, point: Vec3, name: str) -> np.ndarray:
    p = np.asarray(point, dtype=float).reshape(3)
    if grid.index_of(p) is None:
        raise NoPathError(f"{name} {_fmt(p)} is outside the grid")
    if search_grid.is_free(p):
        return p
    snap_radius = SNAP_RADIUS_CELLS * grid.resolution
    snapped = search_grid.nearest_free(p, snap_radius)
    if snapped is None:
        where = "is blocked" if search_grid is grid else "is blocked or outside z_limits"
        raise NoPathError(f"{name} {_fmt(p)} {where} and no free cell lies within {snap_radius:.2f} m")
    return snapped


def _astar(
    grid: OccupancyGrid, start: np.ndarray, goal: np.ndarray, max_expansions: int, field: np.ndarray | None = None
) -> list[np.ndarray]:
    """Indices of the cells from the start cell to the goal cell, both included; `field`: cells from each cell
    to the goal through the travel graph (`_guided_heuristic`)."""
    # A one-cell blocked border makes every neighbour index of a grid cell valid: no bounds checks.
    padded_free = np.pad(~grid.occupied, 1, constant_values=False)
    shape = padded_free.shape
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    steps_used = np.all((_NEIGHBOUR_STEPS == 0) | (np.array(grid.shape) > 1), axis=1)  # a flat grid: 8 steps
    neighbours = list(zip((_NEIGHBOUR_STEPS[steps_used] @ strides).tolist(), _STEP_LENGTHS[steps_used].tolist()))
    start_cell = np.asarray(grid.index_of(start)) + 1
    goal_cell = np.asarray(grid.index_of(goal)) + 1
    start_flat = int(start_cell @ strides)
    goal_flat = int(goal_cell @ strides)

    # The search loop runs in plain Python on flat buffers: for 26 neighbours, per-element access through a
    # memoryview beats numpy's per-call overhead about twice over (measured), and a memoryview of the numpy
    # arrays copies nothing (array.array copies took 10 ms a search in a hall's grid).
    octile = _octile_distance_to(goal_cell, shape)
    guided = octile if field is None else _guided_heuristic(octile, field)
    guided *= HEURISTIC_WEIGHT
    heuristic = _buffer(guided.ravel())
    step_cost = _buffer(_step_cost_factors(grid).ravel())
    open_cells = _buffer(padded_free.ravel().view(np.uint8))  # padded_free is this search's own copy
    cost = _buffer(np.full(padded_free.size, np.inf))
    parent = _buffer(np.full(padded_free.size, -1, dtype=np.int64))
    cost[start_flat] = 0.0
    heap = [(heuristic[start_flat], 0.0, start_flat)]
    push, pop = heapq.heappush, heapq.heappop
    expansions = 0
    while heap:
        cell = pop(heap)[2]
        if not open_cells[cell]:
            continue  # stale entry: already expanded through a cheaper one
        if cell == goal_flat:
            return _trace(parent, goal_flat, shape)
        open_cells[cell] = 0
        expansions += 1
        if expansions > max_expansions:
            raise _GaveUp(f"search gave up after {max_expansions} expansions")
        cell_cost = cost[cell]
        for offset, length in neighbours:
            neighbour = cell + offset
            if open_cells[neighbour]:
                new_cost = cell_cost + length * step_cost[neighbour]
                if new_cost < cost[neighbour]:
                    cost[neighbour] = new_cost
                    parent[neighbour] = cell
                    # Ties on f go to the deeper node (higher cost so far): far fewer expansions on plateaus.
                    push(heap, (new_cost + heuristic[neighbour], -new_cost, neighbour))
    raise NoPathError(f"goal {_fmt(goal)} is unreachable from start {_fmt(start)} ({expansions} cells searched)")


def _buffer(array: np.ndarray) -> Any:
    """A memoryview of a contiguous 1-D array: items read and written at C speed, nothing copied."""
    return memoryview(array)  # type: ignore[arg-type]  # numpy's stubs do not declare the buffer protocol


def _step_cost_factors(grid: OccupancyGrid) -> np.ndarray:
    """Per padded cell, what a step into it costs per unit of length: 1, or NOT_ROOMY_COST where the grid marks
    roomy cells and this is not one (>= 1 everywhere: the octile heuristic stays admissible)."""
    factors = np.ones(tuple(n + 2 for n in grid.shape))
    if grid.roomy is not None:
        factors[1:-1, 1:-1, 1:-1] = np.where(grid.roomy, 1.0, NOT_ROOMY_COST)
    return factors


def _octile_distance_to(goal_cell: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Shortest 26-connected distance (in cells) from every cell to `goal_cell`, ignoring obstacles:
    (large - middle) + sqrt2 (middle - small) + sqrt3 small of the three axis distances.

    Admissible and consistent for Euclidean step costs, and much tighter than the straight-line distance,
    which in 3D leaves A* expanding a wide ellipsoid of near-ties. The x-y extremes are taken on the plane and
    the rest computed in place: three whole-grid arrays instead of a dozen (a hall's grid: 10 -> 5 ms), the same values.
    """
    dx, dy, dz = (np.abs(np.arange(n, dtype=float) - g) for n, g in zip(shape, goal_cell))
    dx, dy = dx[:, None], dy[None, :]
    dz = dz[None, None, :]
    large: np.ndarray = np.maximum(np.maximum(dx, dy)[:, :, None], dz)
    small = np.minimum(np.minimum(dx, dy)[:, :, None], dz)
    middle = (dx + dy)[:, :, None] + dz
    middle -= large
    middle -= small
    large -= middle  # large - middle
    middle -= small
    middle *= _SQRT2  # sqrt2 (middle - small)
    large += middle
    small *= _SQRT3
    large += small
    return large


def _guided_heuristic(octile: np.ndarray, field: np.ndarray) -> np.ndarray:
    """The octile distance (padded grid) raised to the way through the travel graph (`field`, unpadded, in cells)
    less GUIDE_SLACK_CELLS, where the graph reaches. The graph measures between the centres of 2x2x2 merged
    cells, and a cell's centre lies up to sqrt(3) cells from its merged cell's, at either end: the slack keeps
    the estimate under the way a drone could take, nearly everywhere (where the merge shortens a way round a
    slanted wall it is over; A* then returns a free path that may not be the shortest). Where the straight line
    points at a wall the way round does not, so A* follows the way instead of filling every room on the wrong
    side (a two-storey building: 7.9 s for one path, the drone hovering meanwhile)."""
    padded = np.pad(np.where(np.isfinite(field), field - GUIDE_SLACK_CELLS, 0.0), 1)
    guided: np.ndarray = np.maximum(octile, padded)
    return guided


def _trace(parent: Any, goal_flat: int, shape: tuple[int, ...]) -> list[np.ndarray]:
    flat = [goal_flat]
    while parent[flat[-1]] >= 0:
        flat.append(parent[flat[-1]])
    padded = np.stack(np.unravel_index(np.array(flat[::-1]), shape), axis=1)
    return list(padded - 1)


def _shortcut(grid: OccupancyGrid, points: list[np.ndarray]) -> list[np.ndarray]:
    """Greedy string pulling: from each kept point, go straight to the last point before one is out of sight.

    Consecutive points are adjacent cells of the A* path, so every kept segment is either checked here or one
    A* step; each step between neighbouring free cells is itself free.
    """
    if len(points) <= 2:
        return points
    kept = [points[0]]
    anchor = points[0]
    for previous, candidate in zip(points[1:-1], points[2:]):
        if not grid.segment_is_free(anchor, candidate):
            kept.append(previous)
            anchor = previous
    kept.append(points[-1])
    return kept


def _drop_repeats(points: list[np.ndarray]) -> list[np.ndarray]:
    kept = [points[0]]
    for p in points[1:-1]:
        if not np.array_equal(p, kept[-1]):
            kept.append(p)
    if len(kept) > 1 and np.array_equal(kept[-1], points[-1]):
        kept.pop()
    kept.append(points[-1])
    return kept


def _as_vec3(p: np.ndarray) -> Vec3:
    return float(p[0]), float(p[1]), float(p[2])


def _fmt(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:.2f}" for v in p) + ")"
