"""The exploration oracle: how long N drones would need to see 95 % of a building they knew in advance.

It is the yardstick of `swarm bench explore`: a mission's time to 95 % over the oracle's, for the same world and
number of drones, says how far exploration is from the limit. Its space is the report's: the reachable free cells
of `swarm.sim.coverage` (0.2 m, drone-radius clearance, the component of the take-off point), and a cell counts as
seen as the map would know it.

1. Cells. The reachable cells at even indices on each axis (a 0.4 m lattice, 1/8 of them: a uniform sample of
   the same space) are both what the views must see and the nodes of the routing graph.
2. Candidate views. Every node on a `view_spacing_m` grid whose height is nearest one of the flight levels
   (take-off floor + agent.altitude_m + k * `level_spacing_m`, inside the flight band of `swarm.explore`:
   min_altitude_m above the volume's floor, ceiling_margin_m below its top) and that is airframe-safe
   (explore.clearance_m from the mesh at the position, half-way up and at body_height_m above it), times
   `headings` yaws. Only nodes the routing graph connects to the take-off point are kept.
3. What a view sees. From each candidate position one panorama of rays (`pano_step_deg` apart over 360 degrees
   of azimuth and the camera's elevations) is cast on the true mesh (Open3D `RaycastingScene`, as the simulated
   camera does). A cell is seen from a view when it lies in the camera's frustum (camera.hfov_deg, the vertical
   FOV of its aspect ratio, camera.pitch_deg), nearer than the surface the ray towards it hits, and that hit's
   z-depth is within [min_range_m, max_range_m]: a TSDF integrates a voxel only through a pixel with a valid
   return, and a pixel without one carves nothing (`swarm.patches.carving`).
4. Cover. Lazy greedy set cover on the sampled cells until `target` of them are seen and `target` of every
   reachable 0.2 m cell is (checked on the full set with the same test, so the figure is the report's).
5. Routes. Geodesic distances between the chosen views and the spawn points (`spawn_points`, as `swarm run`
   places the drones, lifted to agent.altitude_m) by Dijkstra on the node graph (26-neighbours whose midpoint
   0.2 m cell is reachable). One open tour from the first spawn through every view (nearest neighbour, then
   2-opt) is cut into N consecutive legs, one per drone, by an exact min-max split (a leg is entered at its
   nearer end); then the drone with the longest time gives views to others by cheapest insertion while that
   shortens the longest time, and each route is 2-opted from its spawn. An N-drone plan is never worse than the
   best plan for fewer drones (the extra drones may stay on the ground).
6. Flight. Each drone sees on the way too: at every node of its path it looks along its direction of travel (the
   nearest heading), and at each view for explore.dwell_s. The time to 95 % is when the swarm's frames together
   have seen `target` of the sampled cells. Views whose removal makes that time shorter (what they alone see is
   seen on the way) are dropped, fewest unique cells first, and the routes planned again.
7. A second plan, a sweep: the drone free first flies to the candidate view with the most unseen cells per second
   of flight and dwell from where it is, until `target` is seen; timed the same way. The faster plan is kept
   (`notes` says which): the cover plans views for what they see, not where they are, and in a building of rooms
   off one corridor the sweep, which glances into each room on the way, was 10-20 % faster.
8. Time per drone: take-off (agent.altitude_m at sim.max_speed_up_m_s) + route length / agent.cruise_speed_m_s +
   explore.dwell_s per view; the oracle's time to 95 % is the largest.

It is a heuristic, so its time is an upper bound of the true optimum of this model; the model itself is
favourable to the oracle in some ways (flight at cruise speed from the first metre, no turns, the building known)
and unfavourable in others (only the views count, nothing seen on the way). Its clock starts at take-off; a
mission's starts when the agent processes do, about 5 s earlier. Cost (measured, 2 cores, 1-3 drones): box 0.7 s,
office (30 x 20 x 3 m) 6 s, warehouse (40 x 25 x 6 m, five flight levels) 48 s (cover 12 s, then the routes,
pruning and sweep per size); a 40 x 30 x 3 m floor should take ~10 s.
"""

from __future__ import annotations

import heapq
import itertools
import math
import time
from dataclasses import asdict, dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from swarm.config import SwarmConfig, Vec3
from swarm.patches.backend import tensor
from swarm.sim.coverage import ReachableSpace, mission_reachable_space
from swarm.sim.worlds import World, mission_volume, spawn_points

TARGET = 0.95
VIEW_SPACING_M = 1.2
LEVEL_SPACING_M = 1.0
HEADINGS = 8
PANO_STEP_DEG = 2.5
_STRIDE = 2  # sampled cells and graph nodes: every second reachable cell on each axis
_DIJKSTRA_CHUNK = 32  # sources per Dijkstra call: bounds the (sources, nodes) distance block
_MAX_REBALANCE = 400
_MAX_PRUNE = 200  # rounds of view pruning
_PRUNE_TRIES = 4  # views tried for removal per round, fewest unique cells first


@dataclass(frozen=True)
class OracleView:
    position: Vec3
    yaw_deg: float


@dataclass
class OraclePlan:
    """The oracle's plan for `drones` drones; time_to_95_s is None when the candidate views cannot see `target`."""

    drones: int
    target: float
    time_to_95_s: float | None
    coverage: float  # share of the reachable 0.2 m cells the chosen views see
    best_possible: float  # share of the sampled cells all candidate views together see
    views: list[OracleView]
    routes: list[list[int]]  # per drone, indices into views in flight order
    route_m: list[float]
    drone_s: list[float]
    candidates: int
    compute_s: float = 0.0
    notes: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out["views"] = [{"position": list(v.position), "yaw_deg": v.yaw_deg} for v in self.views]
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> OraclePlan:
        views = [OracleView(tuple(v["position"]), float(v["yaw_deg"])) for v in data["views"]]  # type: ignore[arg-type]
        return cls(**{**data, "views": views})


@dataclass
class _Cells:
    """A set of cells on a regular lattice, with a dense grid of their indices for box queries."""

    origin: np.ndarray  # world corner of lattice cell (0, 0, 0)
    pitch: float
    ids: np.ndarray  # (nx, ny, nz) int32, -1 where no cell
    centres: np.ndarray  # (N, 3)

    @classmethod
    def from_mask(cls, origin: np.ndarray, pitch: float, mask: np.ndarray) -> _Cells:
        ids = np.full(mask.shape, -1, dtype=np.int32)
        where = np.argwhere(mask)
        ids[tuple(where.T)] = np.arange(len(where), dtype=np.int32)
        return cls(origin, pitch, ids, origin + (where + 0.5) * pitch)

    def near(self, p: np.ndarray, radius: float) -> np.ndarray:
        lo = np.maximum(np.floor((p - radius - self.origin) / self.pitch).astype(int), 0)
        hi = np.minimum(np.ceil((p + radius - self.origin) / self.pitch).astype(int) + 1, self.ids.shape)
        block = self.ids[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
        return block[block >= 0]


class Oracle:
    """The views, their cover and the distances of one world (independent of N); `plan(n)` routes them."""

    def __init__(
        self,
        world: World,
        config: SwarmConfig,
        *,
        target: float = TARGET,
        view_spacing_m: float = VIEW_SPACING_M,
        level_spacing_m: float = LEVEL_SPACING_M,
        headings: int = HEADINGS,
        pano_step_deg: float = PANO_STEP_DEG,
    ) -> None:
        if not 0.0 < target <= 1.0:
            raise ValueError("target must be in (0, 1]")
        self.world, self.config, self.target = world, config, target
        self.view_spacing_m, self.level_spacing_m, self.headings = view_spacing_m, level_spacing_m, headings
        self.pano_step = math.radians(pano_step_deg)
        self.space: ReachableSpace = mission_reachable_space(world, config)
        self.full = _Cells.from_mask(self.space.origin, self.space.resolution, self.space.mask)
        # nodes: the sampled cells, on a lattice of pitch 2 res whose cell (i, j, k) holds fine cell (2i, 2j, 2k)
        coarse = self.space.mask[::_STRIDE, ::_STRIDE, ::_STRIDE]
        self.nodes = _Cells.from_mask(self.space.origin, self.space.resolution * _STRIDE, coarse)
        self.nodes.centres = self.space.origin + (np.argwhere(coarse) * _STRIDE + 0.5) * self.space.resolution
        self._plans: dict[int, OraclePlan] = {}
        self._panos: dict[int, np.ndarray] = {}  # node -> flattened panorama (rows x columns)
        self._seen: dict[int, list[np.ndarray]] = {}  # node -> per heading, the sampled cells it sees
        cam = config.camera
        self.tan_h = math.tan(math.radians(cam.hfov_deg) / 2)
        self.tan_v = self.tan_h * cam.height / cam.width
        self.max_range = cam.max_range_m * math.sqrt(1 + self.tan_h**2 + self.tan_v**2)  # frustum corner
        self._t0 = time.monotonic()

    # --- graph and candidates ----------------------------------------------------------------------------------

    @cached_property
    def graph(self) -> Any:
        """Undirected node graph: 26-neighbours on the node lattice whose midpoint fine cell is reachable."""
        ids, fine = self.nodes.ids, self.space.mask
        rows, cols, weights = [], [], []
        shape = np.array(ids.shape)
        for d in _FORWARD_OFFSETS:
            lo = np.maximum(-d, 0)
            hi = shape - np.maximum(d, 0)
            a = ids[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
            b = ids[lo[0] + d[0] : hi[0] + d[0], lo[1] + d[1] : hi[1] + d[1], lo[2] + d[2] : hi[2] + d[2]]
            ok = (a >= 0) & (b >= 0)
            where = np.argwhere(ok) + lo
            mid = where * _STRIDE + d
            inside = np.all(mid < np.array(fine.shape), axis=1)
            keep = np.zeros(len(where), dtype=bool)
            keep[inside] = fine[tuple(mid[inside].T)]
            rows.append(a[ok][keep])
            cols.append(b[ok][keep])
            weights.append(np.full(int(keep.sum()), float(np.linalg.norm(d)) * self.nodes.pitch))
        n = len(self.nodes.centres)
        r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)
        return coo_matrix((w, (r, c)), shape=(n, n)).tocsr()

    def spawn_nodes(self, n: int) -> list[int]:
        m, agent = self.config.mission, self.config.agent
        spawns = np.array(spawn_points(self.world, m.start, n, m.spawn_spacing_m), dtype=float)
        airborne = spawns + [0.0, 0.0, agent.altitude_m]
        _, nearest = self._node_tree.query(airborne)
        return [int(i) for i in np.atleast_1d(nearest)]

    @cached_property
    def _node_tree(self) -> cKDTree:
        return cKDTree(self.nodes.centres)

    @cached_property
    def candidates(self) -> np.ndarray:
        """Node indices of the candidate view positions (see the module docstring, 2)."""
        cfg, ex = self.config, self.config.explore
        lo, hi = mission_volume(self.world, cfg.mission.volume)
        centres = self.nodes.centres
        idx = np.argwhere(self.nodes.ids >= 0)
        step = max(1, round(self.view_spacing_m / self.nodes.pitch))
        on_grid = (idx[:, 0] % step == 0) & (idx[:, 1] % step == 0)
        floor = self.world.default_start[2] if cfg.mission.start is None else cfg.mission.start[2]
        band = (lo[2] + ex.min_altitude_m, hi[2] - ex.ceiling_margin_m)
        base = floor + cfg.agent.altitude_m
        k = np.arange(
            math.floor((band[0] - base) / self.level_spacing_m), math.ceil((band[1] - base) / self.level_spacing_m) + 1
        )
        levels = base + k * self.level_spacing_m
        levels = levels[(levels >= band[0]) & (levels <= band[1])]
        layer_z = np.unique(centres[:, 2])
        chosen_z: np.ndarray = (
            np.unique(layer_z[np.abs(layer_z[None, :] - levels[:, None]).argmin(axis=1)])
            if len(levels)
            else np.zeros(0)
        )
        keep = on_grid & np.isin(centres[:, 2], chosen_z) & (centres[:, 2] >= band[0]) & (centres[:, 2] <= band[1])
        pick = np.flatnonzero(keep)
        for lift in (0.0, ex.body_height_m / 2, ex.body_height_m):
            pts = centres[pick] + [0.0, 0.0, lift]
            pick = pick[self.world.distance(pts) >= ex.clearance_m]
        _, labels = connected_components(self.graph, directed=False)
        home = self.spawn_nodes(1)[0]
        return pick[labels[pick] == labels[home]]

    # --- visibility --------------------------------------------------------------------------------------------

    @cached_property
    def _elevations(self) -> tuple[float, int]:
        """Lowest elevation of the panoramas and their number of rows: the pitched frustum's, one row of margin."""
        pitch = math.radians(self.config.camera.pitch_deg)
        s = np.linspace(-1.0, 1.0, 41)
        edge = np.concatenate(
            [np.stack([s, np.full_like(s, v)], 1) for v in (-1.0, 1.0)]
            + [np.stack([np.full_like(s, u), s], 1) for u in (-1.0, 1.0)]
        )
        x, y = edge[:, 0] * self.tan_h, edge[:, 1] * self.tan_v  # camera right, down, forward 1
        up = -y * math.cos(pitch) - math.sin(pitch)
        fwd = math.cos(pitch) - y * math.sin(pitch)
        el = np.arctan2(up, np.hypot(fwd, x))
        lo = max(-math.pi / 2, float(el.min()) - self.pano_step)
        hi = min(math.pi / 2, float(el.max()) + self.pano_step)
        return lo, max(1, math.ceil((hi - lo) / self.pano_step))

    @cached_property
    def _pano_dirs(self) -> np.ndarray:
        el_lo, rows = self._elevations
        cols = math.ceil(2 * math.pi / self.pano_step)
        az = -math.pi + (np.arange(cols) + 0.5) * (2 * math.pi / cols)
        el = el_lo + (np.arange(rows) + 0.5) * self.pano_step
        e, a = np.meshgrid(el, az, indexing="ij")
        return np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1).reshape(-1, 3)

    def _bins(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Panorama row and column of directions v (N, 3), rows clipped to the panorama."""
        el_lo, rows = self._elevations
        cols = math.ceil(2 * math.pi / self.pano_step)
        r = np.linalg.norm(v, axis=1)
        row = np.floor((np.arcsin(np.clip(v[:, 2] / np.maximum(r, 1e-12), -1, 1)) - el_lo) / self.pano_step)
        col = np.floor((np.arctan2(v[:, 1], v[:, 0]) + math.pi) / (2 * math.pi) * cols).astype(int) % cols
        return np.clip(row.astype(int), 0, rows - 1), col

    def _panoramas(self, nodes: np.ndarray) -> None:
        """Cast the panoramas of the nodes that have none yet: hit distance per direction, inf for none."""
        todo = [int(n) for n in np.unique(nodes) if int(n) not in self._panos]
        if not todo:
            return
        dirs = self._pano_dirs
        eyes = self.nodes.centres[todo]
        chunk = max(1, 4_000_000 // len(dirs))
        for s in range(0, len(eyes), chunk):
            part = eyes[s : s + chunk]
            rays = np.empty((len(part), len(dirs), 6), dtype=np.float32)
            rays[:, :, :3] = part[:, None, :]
            rays[:, :, 3:] = dirs[None, :, :]
            hit = self.world.scene.cast_rays(tensor(rays.reshape(-1, 6)))["t_hit"].numpy()
            for node, pano in zip(todo[s : s + chunk], hit.reshape(len(part), -1)):
                self._panos[node] = pano.astype(np.float32)

    @cached_property
    def _frames(self) -> np.ndarray:
        """(headings, 3, 3): rows right, down, forward of the camera at each heading (as `camera_pose`)."""
        pitch = math.radians(self.config.camera.pitch_deg)
        frames = []
        for h in range(self.headings):
            yaw = 2 * math.pi * h / self.headings
            fwd = np.array([math.cos(yaw) * math.cos(pitch), math.sin(yaw) * math.cos(pitch), -math.sin(pitch)])
            right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
            frames.append(np.stack([right, np.cross(fwd, right), fwd]))
        return np.array(frames)

    def _in_view(self, v: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For offsets v (N, 3) at ranges r: (N, headings) inside the frustum with z-depth in range, and z / r."""
        cam = v @ self._frames.reshape(-1, 3).T  # (N, headings * 3): right, down, forward per heading
        x, y, z = cam[:, 0::3], cam[:, 1::3], cam[:, 2::3]
        inside = (z > 0) & (np.abs(x) <= z * self.tan_h) & (np.abs(y) <= z * self.tan_v)
        inside &= z <= self.config.camera.max_range_m
        return inside, z / np.maximum(r, 1e-12)[:, None]

    @cached_property
    def _offsets(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray], list[np.ndarray]]:
        """Node-lattice offsets some heading's frustum holds within range: (offsets, range, pano bin, per heading
        the offsets' rows and their z / r). Eyes and sampled cells share the lattice, so these are exact."""
        pitch, shape = self.nodes.pitch, self.nodes.ids.shape
        reach = math.ceil(self.max_range / pitch)
        axes = [np.arange(-reach, reach + 1)] * 2 + [np.arange(-(shape[2] - 1), shape[2])]
        off = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        v = off * pitch
        r = np.linalg.norm(v, axis=1)
        keep = (r > 0) & (r <= self.max_range)
        off, v, r = off[keep], v[keep], r[keep]
        inside, zr = self._in_view(v, r)
        keep = inside.any(axis=1)
        off, v, r, inside, zr = off[keep], v[keep], r[keep], inside[keep], zr[keep]
        row, col = self._bins(v)
        flat = row * math.ceil(2 * math.pi / self.pano_step) + col
        rows = [np.flatnonzero(inside[:, h]) for h in range(self.headings)]
        return off, r.astype(np.float32), flat, rows, [zr[i, h].astype(np.float32) for h, i in enumerate(rows)]

    def seen_from(self, node: int) -> list[np.ndarray]:
        """Per heading, the sampled cells (node indices) the camera at `node` sees (module docstring, 3)."""
        got = self._seen.get(node)
        if got is not None:
            return got
        self._panoramas(np.array([node]))
        off, r, flat, rows, zrs = self._offsets
        cells = self._node_index[node] + off
        shape = np.array(self.nodes.ids.shape)
        inb = np.all((cells >= 0) & (cells < shape), axis=1)
        ids = np.full(len(off), -1, dtype=np.int32)
        ids[inb] = self.nodes.ids[tuple(cells[inb].T)]
        hit = self._panos[node][flat]
        visible = (ids >= 0) & (r < hit)
        cam = self.config.camera
        out = []
        for sel, zr in zip(rows, zrs):
            ok = visible[sel]
            depth = hit[sel[ok]] * zr[ok]
            good = (depth >= cam.min_range_m) & (depth <= cam.max_range_m)
            out.append(ids[sel[ok][good]])
        self._seen[node] = out
        return out

    def seen_full(self, node: int, heading: int) -> np.ndarray:
        """The reachable 0.2 m cells (indices into the space's centres) the camera at `node` sees at `heading`."""
        self._panoramas(np.array([node]))
        eye = self.nodes.centres[node]
        near = self.full.near(eye, self.max_range)
        v = self.full.centres[near] - eye
        r = np.linalg.norm(v, axis=1)
        ok = (r > 0) & (r <= self.max_range)
        near, v, r = near[ok], v[ok], r[ok]
        row, col = self._bins(v)
        hit = self._panos[node][row * math.ceil(2 * math.pi / self.pano_step) + col]
        inside, zr = self._in_view(v, r)
        depth = hit * zr[:, heading]
        cam = self.config.camera
        mask = inside[:, heading] & (r < hit) & (depth >= cam.min_range_m) & (depth <= cam.max_range_m)
        return near[mask]

    @cached_property
    def _node_index(self) -> np.ndarray:
        return np.argwhere(self.nodes.ids >= 0)

    # --- cover -------------------------------------------------------------------------------------------------

    @cached_property
    def cover(self) -> tuple[list[tuple[int, int]], float, float]:
        """Greedy cover: the chosen (node, heading) views, the share of the reachable 0.2 m cells they see, and the
        share of the sampled cells all candidate views together see."""
        n_sampled, n_full = len(self.nodes.centres), len(self.full.centres)
        self._panoramas(self.candidates)
        heap: list[tuple[int, int, int]] = []
        everything = np.zeros(n_sampled, dtype=bool)
        for node in self.candidates:
            for h, cells in enumerate(self.seen_from(int(node))):
                everything[cells] = True
                if len(cells):
                    heap.append((-len(cells), int(node), h))
        heapq.heapify(heap)
        covered, covered_full = np.zeros(n_sampled, dtype=bool), np.zeros(n_full, dtype=bool)
        count = count_full = 0
        chosen: list[tuple[int, int]] = []
        need, need_full = math.ceil(self.target * n_sampled - 1e-9), math.ceil(self.target * n_full - 1e-9)
        while heap and (count < need or count_full < need_full):
            _, node, h = heapq.heappop(heap)
            cells = self.seen_from(node)[h]
            gain = int(np.count_nonzero(~covered[cells]))
            if gain == 0:
                continue
            if heap and gain < -heap[0][0]:
                heapq.heappush(heap, (-gain, node, h))
                continue
            chosen.append((node, h))
            covered[cells] = True
            count += gain
            covered_full[self.seen_full(node, h)] = True
            count_full = int(np.count_nonzero(covered_full))
        return chosen, count_full / max(1, n_full), float(everything.mean()) if n_sampled else 0.0

    # --- routes ------------------------------------------------------------------------------------------------

    def _distances(self, nodes: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """Geodesic distances between `nodes` (K, K) and each one's Dijkstra predecessors (K, all nodes)."""
        out = np.empty((len(nodes), len(nodes)))
        preds = np.empty((len(nodes), len(self.nodes.centres)), dtype=np.int32)
        for s in range(0, len(nodes), _DIJKSTRA_CHUNK):
            block, pred = dijkstra(
                self.graph, directed=False, indices=nodes[s : s + _DIJKSTRA_CHUNK], return_predecessors=True
            )
            out[s : s + _DIJKSTRA_CHUNK] = block[:, nodes]
            preds[s : s + _DIJKSTRA_CHUNK] = pred
        return out, preds

    def plan(self, drones: int) -> OraclePlan:
        """The plan for `drones` drones (computed once per size; never slower than one for fewer drones)."""
        if drones < 1:
            raise ValueError("drones must be at least 1")
        if drones in self._plans:
            return self._plans[drones]
        chosen, coverage, best = self.cover
        spawns = self.spawn_nodes(drones)
        reached = coverage >= self.target - 1e-9
        routes, t95 = self._fly_cover(chosen, spawns)
        method = "cover"
        if reached:
            sweep, sweep_routes = self._sweep(spawns)
            sweep_t95 = self._time_of(sweep, sweep_routes, spawns)[1]
            if sweep_t95 < t95:
                chosen, routes, t95, method = sweep, sweep_routes, sweep_t95, "sweep"
        dist = self._distances([n for n, _ in chosen] + spawns)[0]
        k = len(chosen)
        views = [OracleView(_vec3(self.nodes.centres[n]), round(360.0 * h / self.headings, 3)) for n, h in chosen]
        route_m = [_route_length(dist, k + i, r) for i, r in enumerate(routes)]
        drone_s = [self._drone_time(m, len(r)) for m, r in zip(route_m, routes)]
        notes = [f"plan: {method}"]
        if not reached:
            notes.append(f"the candidate views see {100 * coverage:.1f} % of the reachable space")
        plan = OraclePlan(
            drones,
            self.target,
            round(t95, 2) if reached and math.isfinite(t95) else None,
            round(coverage, 4),
            round(best, 4),
            views,
            routes,
            [round(m, 2) for m in route_m],
            [round(s, 2) for s in drone_s],
            len(self.candidates) * self.headings,
            notes=notes,
        )
        if drones > 1:
            fewer = self.plan(drones - 1)
            if (
                fewer.time_to_95_s is not None
                and plan.time_to_95_s is not None
                and fewer.time_to_95_s < plan.time_to_95_s
            ):
                plan = OraclePlan(
                    **{
                        **fewer.__dict__,
                        "drones": drones,
                        "routes": fewer.routes + [[]],
                        "route_m": fewer.route_m + [0.0],
                        "drone_s": fewer.drone_s + [0.0],
                        "notes": fewer.notes + [f"drone {drones} stays on the ground"],
                    }
                )
        plan.compute_s = round(time.monotonic() - self._t0, 2)
        self._plans[drones] = plan
        return plan

    def _fly_cover(self, chosen: list[tuple[int, int]], spawns: list[int]) -> tuple[list[list[int]], float]:
        """Routes over the cover's views (indices into `chosen`), pruned, and their time to target."""
        k = len(chosen)
        nodes, headings = [n for n, _ in chosen] + spawns, [h for _, h in chosen]
        dist, preds = self._distances(nodes)
        starts = list(range(k, k + len(spawns)))

        def fly(active: list[int]) -> tuple[list[list[int]], float, dict[int, int]]:
            routes = _min_max_routes(dist, active, starts, self._view_cost)
            return (routes, *self._time_to_target(routes, nodes, headings, preds, starts))

        routes, t95, unique = fly(list(range(k)))
        return self._prune(fly, routes, t95, unique)

    def _time_of(
        self, chosen: list[tuple[int, int]], routes: list[list[int]], spawns: list[int]
    ) -> tuple[list[list[int]], float]:
        k = len(chosen)
        nodes, headings = [n for n, _ in chosen] + spawns, [h for _, h in chosen]
        preds = self._distances(nodes)[1]
        return routes, self._time_to_target(routes, nodes, headings, preds, list(range(k, k + len(spawns))))[0]

    def _sweep(self, spawns: list[int]) -> tuple[list[tuple[int, int]], list[list[int]]]:
        """The second plan: each drone in turn (the one free first) flies to the candidate view with the most
        unseen cells per second of flight and dwell from where it is (cells count as seen once a drone is sent to
        see them), until `target` of the sampled cells is seen. Lazy: a view's unseen count only falls."""
        cfg = self.config
        speed, dwell = cfg.agent.cruise_speed_m_s, cfg.explore.dwell_s
        views = [(int(n), h) for n in self.candidates for h in range(self.headings)]
        view_node = np.array([n for n, _ in views])
        upper = np.array([len(self.seen_from(n)[h]) for n, h in views], dtype=float)
        covered = np.zeros(len(self.nodes.centres), dtype=bool)
        need, count = math.ceil(self.target * len(covered) - 1e-9), 0
        free_at = [0.0] * len(spawns)
        here = list(spawns)
        picked: list[tuple[int, int]] = []
        routes: list[list[int]] = [[] for _ in spawns]
        while count < need:
            d = int(np.argmin(free_at))
            # scipy-stubs allow only arrays of indices; one index is fine (and gives one row, 1-D)
            travel = dijkstra(self.graph, directed=False, indices=here[d])[view_node] / speed + dwell  # type: ignore[call-overload]
            score = np.where(np.isfinite(travel), upper / travel, 0.0)
            order = np.argsort(-score)
            best, best_score = -1, 0.0
            for v in order:
                if score[v] <= best_score or score[v] <= 0:
                    break
                n, h = views[v]
                upper[v] = float(np.count_nonzero(~covered[self.seen_from(n)[h]]))
                exact = upper[v] / travel[v]
                if exact > best_score:
                    best, best_score = int(v), exact
            if best < 0:
                break
            n, h = views[best]
            cells = self.seen_from(n)[h]
            count += int(np.count_nonzero(~covered[cells]))
            covered[cells] = True
            upper[best] = 0.0
            free_at[d] += float(travel[best])
            here[d] = n
            routes[d].append(len(picked))
            picked.append((n, h))
        return picked, routes

    def _prune(
        self, fly: Any, routes: list[list[int]], t95: float, unique: dict[int, int]
    ) -> tuple[list[list[int]], float]:
        """Drop views the flight no longer needs (what they alone see is seen on the way, or is beyond the target),
        fewest unique cells first, while that makes the time to target shorter."""
        for _ in range(_MAX_PRUNE):
            active = [v for r in routes for v in r]
            for v in sorted(active, key=lambda v: (unique.get(v, 0), v))[:_PRUNE_TRIES]:
                trial = fly([a for a in active if a != v])
                if trial[1] < t95 - 1e-6:
                    routes, t95, unique = trial
                    break
            else:
                break
        return routes, t95

    def _time_to_target(
        self, routes: list[list[int]], nodes: list[int], headings: list[int], preds: np.ndarray, starts: list[int]
    ) -> tuple[float, dict[int, int]]:
        """When the swarm flying `routes` has seen `target` of the sampled cells (inf: never), and per view the
        cells only it sees (up to then): each drone looks ahead along its path (the nearest heading to its direction
        of travel) at every node, and at each view for the dwell."""
        cfg = self.config
        speed, dwell = cfg.agent.cruise_speed_m_s, cfg.explore.dwell_s
        takeoff = cfg.agent.altitude_m / cfg.sim.max_speed_up_m_s
        events: list[tuple[float, int, int, int]] = []  # (time, node, heading, view or -1)
        for start, route in zip(starts, routes):
            t, here, heading = takeoff, start, 0
            for v in route:
                path = _path(preds[here], nodes[here], nodes[v])
                for a, b in itertools.pairwise(path):
                    step = self.nodes.centres[b] - self.nodes.centres[a]
                    t += float(np.linalg.norm(step)) / speed
                    if np.hypot(step[0], step[1]) > 1e-9:
                        heading = round(math.atan2(step[1], step[0]) / (2 * math.pi / self.headings)) % self.headings
                    events.append((t, b, heading, -1))
                t += dwell
                events.append((t, nodes[v], headings[v], v))
                here, heading = v, headings[v]
        self._panoramas(np.array([e[1] for e in events], dtype=int))
        events.sort()
        seen_by = np.zeros(len(self.nodes.centres), dtype=np.int32)  # how many frames saw each cell
        only = np.full(len(self.nodes.centres), -1, dtype=np.int64)  # the view event that first saw it
        need, count, t95 = math.ceil(self.target * len(seen_by) - 1e-9), 0, math.inf
        for t, node, heading, view in events:
            cells = self.seen_from(node)[heading]
            count += int(np.count_nonzero(seen_by[cells] == 0))
            seen_by[cells] += 1
            if view >= 0:
                only[cells[seen_by[cells] == 1]] = view
            if count >= need:
                t95 = t
                break
        alone = only[(seen_by == 1) & (only >= 0)]
        views, counts = np.unique(alone, return_counts=True)
        return t95, {int(v): int(c) for v, c in zip(views, counts)}

    @property
    def _view_cost(self) -> float:
        """A view's cost in metres of flight: its dwell at cruise speed."""
        return self.config.explore.dwell_s * self.config.agent.cruise_speed_m_s

    def _drone_time(self, route_m: float, views: int) -> float:
        if views == 0:
            return 0.0
        cfg = self.config
        takeoff = cfg.agent.altitude_m / cfg.sim.max_speed_up_m_s
        return takeoff + route_m / cfg.agent.cruise_speed_m_s + cfg.explore.dwell_s * views


# the 13 neighbour offsets of a 26-neighbourhood that are lexicographically positive: each edge once
_FORWARD_OFFSETS = [np.array(d) - 1 for d in np.ndindex(3, 3, 3) if [c - 1 for c in d] > [0, 0, 0]]


def _vec3(p: np.ndarray) -> Vec3:
    return float(p[0]), float(p[1]), float(p[2])


def _path(pred: np.ndarray, source: int, target: int) -> list[int]:
    """Nodes from source to target along a Dijkstra predecessor row of `source`."""
    out = [target]
    while out[-1] != source:
        out.append(int(pred[out[-1]]))
        if out[-1] < 0:
            return [source, target]
    return out[::-1]


def _route_length(dist: np.ndarray, start: int, route: list[int]) -> float:
    path = [start, *route]
    return float(sum(dist[a, b] for a, b in itertools.pairwise(path)))


def _cost(dist: np.ndarray, start: int, route: list[int], view_cost: float) -> float:
    return _route_length(dist, start, route) + view_cost * len(route) if route else 0.0


def _nearest_neighbour(dist: np.ndarray, start: int, views: list[int]) -> list[int]:
    left, here, out = set(views), start, []
    while left:
        nxt = min(left, key=lambda v: (dist[here, v], v))
        out.append(nxt)
        left.remove(nxt)
        here = nxt
    return out


def _two_opt(dist: np.ndarray, start: int, route: list[int]) -> list[int]:
    """2-opt of an open path from a fixed start (the path's end is free)."""
    path = np.array([start, *route])
    m = len(path)
    improved = True
    while improved and m > 2:
        improved = False
        for i in range(1, m - 1):
            j = np.arange(i + 1, m)
            before = dist[path[i - 1], path[i]] + np.where(j + 1 < m, dist[path[j], path[np.minimum(j + 1, m - 1)]], 0)
            after = dist[path[i - 1], path[j]] + np.where(j + 1 < m, dist[path[i], path[np.minimum(j + 1, m - 1)]], 0)
            delta = after - before
            best = int(np.argmin(delta))
            if delta[best] < -1e-9:
                jj = int(j[best])
                path[i : jj + 1] = path[i : jj + 1][::-1].copy()
                improved = True
    return [int(p) for p in path[1:]]


def _split(dist: np.ndarray, tour: list[int], starts: list[int], view_cost: float) -> list[list[int]]:
    """Exact min-max cut of `tour` into len(starts) consecutive legs (possibly empty), leg i flown by starts[i]
    from the leg's nearer end."""
    k, n = len(tour), len(starts)
    t = np.array(tour)
    legs = np.concatenate([[0.0], np.cumsum(dist[t[:-1], t[1:]])]) if k else np.zeros(0)
    best = np.full((n + 1, k + 1), np.inf)
    cut = np.zeros((n + 1, k + 1), dtype=int)
    best[0, 0] = 0.0
    for d in range(1, n + 1):
        s = starts[d - 1]
        for j in range(k + 1):
            i = np.arange(j + 1)
            if j == 0:
                cost = np.zeros(1)
            else:
                first, last = t[np.minimum(i, j - 1)], t[j - 1]
                cost = np.minimum(dist[s, first], dist[s, last]) + (legs[j - 1] - legs[np.minimum(i, j - 1)])
                cost = cost + view_cost * (j - i)
                cost[j] = 0.0  # empty leg
            total = np.maximum(best[d - 1, : j + 1], cost)
            cut[d, j] = int(np.argmin(total))
            best[d, j] = total[cut[d, j]]
    out: list[list[int]] = []
    j = k
    for d in range(n, 0, -1):
        i = cut[d, j]
        leg = tour[i:j]
        s = starts[d - 1]
        if leg and dist[s, leg[-1]] < dist[s, leg[0]]:
            leg = leg[::-1]
        out.append(leg)
        j = i
    return out[::-1]


def _cheapest_insertion(dist: np.ndarray, start: int, route: list[int], v: int) -> tuple[float, int]:
    """The extra length of inserting view v in the route at its best place, and that place (index in route)."""
    path = np.array([start, *route])
    extra = dist[path[:-1], v] + dist[v, path[1:]] - dist[path[:-1], path[1:]]
    end = float(dist[path[-1], v])  # appended at the free end
    if len(extra) == 0 or end <= extra.min():
        return end, len(route)
    best = int(np.argmin(extra))
    return float(extra[best]), best


def _min_max_routes(dist: np.ndarray, views: list[int], starts: list[int], view_cost: float) -> list[list[int]]:
    """Routes over `views` for drones at `starts`: giant tour, exact split, rebalancing, 2-opt."""
    if not views:
        return [[] for _ in starts]
    tour = _two_opt(dist, starts[0], _nearest_neighbour(dist, starts[0], views))
    routes = [_two_opt(dist, s, r) for s, r in zip(starts, _split(dist, tour, starts, view_cost))]
    for _ in range(_MAX_REBALANCE):
        costs = [_cost(dist, s, r, view_cost) for s, r in zip(starts, routes)]
        worst = int(np.argmax(costs))
        move = None
        for pos, v in enumerate(routes[worst]):
            shorter = routes[worst][:pos] + routes[worst][pos + 1 :]
            donor = _cost(dist, starts[worst], shorter, view_cost)
            for other in range(len(starts)):
                if other == worst:
                    continue
                extra, where = _cheapest_insertion(dist, starts[other], routes[other], v)
                taker = costs[other] + extra + view_cost
                gain = costs[worst] - max(donor, taker)
                if gain > 1e-6 and (move is None or gain > move[0]):
                    move = (gain, pos, other, where, v)
        if move is None:
            break
        _, pos, other, where, v = move
        routes[worst] = _two_opt(dist, starts[worst], routes[worst][:pos] + routes[worst][pos + 1 :])
        routes[other] = _two_opt(dist, starts[other], routes[other][:where] + [v] + routes[other][where:])
    return routes
