"""Frontiers for 3D exploration: where known free space meets unknown space, and where to look at it from.

After Mahdoui's frontier rules (Mahdoui 2018, docs/architecture.md "References"), adapted to a 3D grid and to drones
that plan through known free space only. The input is the coarse state grid of the fused map
(`FusedMap.occupancy_grid`): UNKNOWN, FREE or OCCUPIED per cell, cell (i, j, k) spanning
`origin + [i, i+1) x [j, j+1) x [k, k+1) * res`.

- safe cell: a cell where the drone's reported position may be. It and the
  ceil((body_height_m - res/2) / res) cells above it (the airframe stands above its position; its top, body_height_m
  above the cell's centre, keeps clearance_m like the rest of it) are known
  FREE with no point closer than `clearance_m` to an obstacle (the conservative rasterisation of
  `OccupancyGrid.inflate`), none of the ceil((body_height_m + clearance_m) / res) cells above it is UNKNOWN
  (above the grid counts as unknown: a ceiling nobody saw, the drone's top would touch), and its centre is
  inside the flight band
  z in [floor_z + min_altitude_m, top_z - ceiling_margin_m]. UNKNOWN cells are never safe but are not inflated:
  otherwise every frontier would sit behind a wall of blocked cells. UNKNOWN cells whose centre is within
  `clearance_m` of a `free_points` entry or of the column of ceil((body_height_m + clearance_m) / res) cells
  above it (a drone's own position: space a drone occupies, and has room above, is free), and the cells
  holding those, count as FREE; OCCUPIED is never overridden.
  Obstacles are the occupied voxels when the caller gives them (`occupied_fine`), else the OCCUPIED cells. A
  cell is OCCUPIED when any of its voxels is, so on a 0.2 m grid a wall surface can take up to 0.2 m of a
  doorway on each side: a 1.1 m office door showed 0.8 m of free cells, none of them 0.25 m clear of both jambs,
  and a room stayed unexplored. From the voxels, such a door keeps one or two safe cells whatever its alignment.
- roomy cell: a safe cell that is also safe with `roomy_clearance_m` instead of `clearance_m` (the planner
  keeps to those where it can), when that is the larger.
- reachable: the safe cells 26-connected to the safe cell nearest a position (searched within 1.5 m).
- open unknown: an UNKNOWN cell not 26-adjacent to an OCCUPIED cell (crevices next to obstacles do not count),
  in a 26-connected component of open unknown cells of at least `min_unknown_m3` (specks inside known space do
  not count either).
- frontier cell: a FREE cell 6-adjacent to an open unknown cell of the grid (outside the grid is not unknown: the
  grid is the mission volume) whose centre is within `reach_m` of a reachable cell centre. It may lie outside
  the flight band (low space near the floor is seen from above).
- group: a 26-connected component of frontier cells, split by `cluster_size_m` bins of the cell centres; groups
  of fewer than 2 cells are dropped. Its `point` is the group's cell nearest the group's mean.
- gain: open unknown cells in the (2g+1)^3 cube around a cell, g = round(gain_radius_m / res), times res^3; cells
  outside the grid do not count. Groups with gain < `min_gain_m3` are dropped: this box gain says whether there
  is anything worth seeing there.
- view gain (`explore.gain_model = "view"`, the default): what a candidate is worth is the open unknown volume
  the camera would see from its viewpoint turned to face its point: rays over the camera's field of view, to
  its range, each stopped at the first OCCUPIED cell or the grid's edge, the unknown along them integrated as
  r^2 dr dOmega (unknown space is taken to be see-through, as next-best-view planners do). The box gain ranks a
  spot on the floor beside the take-off point (1-3 m^3) with a doorway onto an unseen room (4-6 m^3), so drones
  spent their first half minute on the floor around them; seen from their viewpoints the two differ fifty-fold.
  Candidates whose view gain is under `min_view_gain_m3` are dropped: not worth a trip.
- viewpoint: the reachable cell nearest `point`, provided the straight line between them crosses no OCCUPIED
  cell (a viewpoint on the far side of a thin wall sees nothing); otherwise the nearest reachable cell within
  `reach_m` that has that line of sight; none, and the group is dropped.

Everything is array work (shifted ORs, connected components, summed-volume tables, gathers at offsets sorted by
distance): scipy's exact distance transform alone costs more than the whole budget on a warehouse-sized grid.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property, lru_cache

import cc3d
import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage

from swarm.config import CameraSettings, ExploreSettings, Vec3
from swarm.explore.grid import OccupancyGrid
from swarm.explore.travel import SEARCH_LIMIT_M, TravelGraph
from swarm.patches.fused import FREE, OCCUPIED, UNKNOWN
from swarm.stages import NO_CLOCK, StageClock

START_SEARCH_RADIUS_M = 1.5  # a position's reachable set starts at the safe cell nearest it, this far at most
POCKET_M3 = 0.5  # a reachable set smaller than this is a pocket the map closed round the drone, not its space
ESCAPE_RADIUS_M = 3.0  # how far a drone in a pocket looks for the open space it came from
_ESCAPE_TRIES = 4096  # nearest open cells tried for a straight, known-free way out
_LINE_OF_SIGHT_STEP = 0.25  # line of sight is sampled every quarter cell: a wall a cell thick is never skipped
_EPS = 1e-9
_BITS = 64
VIEW_RAY_SPACING_DEG = 6.0  # the view gain's rays: 195 for a 90 x 74 degree camera, enough to rank candidates
_DIRECTION_CHUNK = 64  # points whose gain cubes (11^3 cells by default) are gathered at once
_VIEW_CHUNK = 16  # candidates ray-cast at once: bounds the temporaries at ~16 x 200 x 40 samples
YAW_BINS = 360  # the view gain turns the camera to the nearest whole degree (its ray offsets are cached per degree)
LOOK_YAWS = 8  # headings tried for a frontier looked at from its own cell with its unknown straight up or down
LOOK_AHEAD_M = 1.0  # a frontier looked at from its own cell: its point moves this far the way the camera looks
_VIEW_UNKNOWN, _VIEW_STOP = 1, 2  # a view ray counts the first, ends at the second (an obstacle, the grid's edge)


@dataclass(frozen=True)
class ViewModel:
    """What a drone's camera sees from a viewpoint: the frustum the view gain integrates over."""

    hfov_deg: float
    vfov_deg: float
    pitch_deg: float  # positive looks down
    min_range_m: float
    max_range_m: float

    @classmethod
    def from_camera(cls, camera: CameraSettings) -> ViewModel:
        half_h = math.radians(camera.hfov_deg) / 2
        vfov = 2 * math.degrees(math.atan(math.tan(half_h) * camera.height / camera.width))  # square pixels
        return cls(camera.hfov_deg, vfov, camera.pitch_deg, camera.min_range_m, camera.max_range_m)

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit ray directions (R, 3) over the field of view of the camera at yaw 0 (x forward, z up), pitched as
        mounted, about VIEW_RAY_SPACING_DEG apart, and each ray's solid angle (R,)."""
        nh = max(2, math.ceil(self.hfov_deg / VIEW_RAY_SPACING_DEG))
        nv = max(2, math.ceil(self.vfov_deg / VIEW_RAY_SPACING_DEG))
        az = np.radians((np.arange(nh) + 0.5) / nh * self.hfov_deg - self.hfov_deg / 2)
        el = np.radians((np.arange(nv) + 0.5) / nv * self.vfov_deg - self.vfov_deg / 2)
        a, e = (g.ravel() for g in np.meshgrid(az, el, indexing="ij"))
        solid = math.radians(self.hfov_deg / nh) * math.radians(self.vfov_deg / nv) * np.cos(e)
        camera = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=1)
        pitch = math.radians(self.pitch_deg)  # positive looks down: a turn about the camera's left axis
        pitched = np.stack(
            [
                camera[:, 0] * math.cos(pitch) + camera[:, 2] * math.sin(pitch),
                camera[:, 1],
                -camera[:, 0] * math.sin(pitch) + camera[:, 2] * math.cos(pitch),
            ],
            axis=1,
        )
        return pitched, solid


@dataclass(frozen=True)
class Frontier:
    point: Vec3  # centre of the frontier cell nearest to its group's mean (what is to be seen)
    viewpoint: Vec3  # centre of a safe, reachable cell within reach_m of `point` (where the drone flies)
    gain: float  # unknown volume (m^3) in the cube of half-width gain_radius_m around `point`
    cells: int  # frontier cells in the group


class ExplorationGrid:
    """One loop's view of the fused map for exploration: what is safe to fly, what is reachable, where the
    frontiers are."""

    def __init__(
        self,
        origin: np.ndarray,
        resolution: float,
        states: np.ndarray,
        safe: np.ndarray,
        band: tuple[int, int],
        settings: ExploreSettings,
        roomy: np.ndarray | None = None,
        view: ViewModel | None = None,
    ) -> None:
        """Use `from_states`; this only stores what it computed."""
        self.origin, self.resolution, self.settings, self.view = origin, resolution, settings, view
        self._occupied = states == OCCUPIED
        self._free = states == FREE
        # Unknown cells touching an obstacle cell are crevices (floor corners, under furniture) that cameras rarely
        # see and that the coverage measure mostly leaves out (it counts space a drone radius from surfaces):
        # they neither make frontiers nor add gain, else the mission's tail is spent staring into corners.
        self._unknown = _without_specks(
            (states == UNKNOWN) & ~_inflate(self._occupied, 0.5),  # 26-neighbours: 5x cheaper than ndimage's dilation
            round(settings.min_unknown_m3 / resolution**3),
        )
        self._band = band
        self.planning_grid = OccupancyGrid(origin, resolution, ~safe, roomy=roomy)

    @cached_property
    def roomy_grid(self) -> OccupancyGrid:
        """The roomy cells as free, all others blocked (the planning grid itself when roomy cells are off)."""
        roomy = self.planning_grid.roomy
        return self.planning_grid if roomy is None else OccupancyGrid(self.origin, self.resolution, ~roomy)

    @classmethod
    def from_states(
        cls,
        origin: ArrayLike,
        resolution: float,
        states: np.ndarray,
        settings: ExploreSettings,
        floor_z: float,
        top_z: float,
        free_points: Sequence[Vec3] = (),
        occupied_fine: np.ndarray | None = None,
        view: ViewModel | None = None,
    ) -> ExplorationGrid:
        """The grid for one loop; `states` as `FusedMap.occupancy_grid` exports them (not modified).
        `occupied_fine`: the occupied voxels of the same volume at a resolution f times finer (f an integer),
        for the clearance test (see the module docstring). `view`: the camera, for the view gain; without it
        (or with `gain_model = "box"`) frontiers carry the box gain."""
        origin_ = np.asarray(origin, dtype=float).reshape(3)
        states = np.asarray(states, dtype=np.uint8)
        if states.ndim != 3 or not resolution > 0:
            raise ValueError(f"need a 3D state grid and a positive resolution, got {states.shape}, {resolution}")
        # The cells above a position that must be clear too, so that the airframe's top, body_height_m above the
        # cell's centre, keeps clearance_m like the rest of it (clearance_m - res/2 anywhere in the cell): the
        # map may end a voxel short at a lintel's edge (a TSDF erodes convex edges), and that margin absorbs it.
        body_cells = _body_cells(settings.body_height_m, resolution)
        # Unknown space is not inflated (see the module docstring), but the airframe and its clearance above it
        # must have been seen: cameras look ahead, and a ceiling nobody looked at is unknown, not absent.
        seen_cells = math.ceil((settings.body_height_m + settings.clearance_m) / resolution - _EPS)
        column = np.array([[0.0, 0.0, j * resolution] for j in range(max(seen_cells, body_cells + 1))])
        body_points = [tuple(np.asarray(p, dtype=float) + c) for p in free_points for c in column]
        states = _mark_free(states, origin_, resolution, body_points, settings.clearance_m)
        roomy_wanted = settings.roomy_clearance_m > settings.clearance_m
        radii = (settings.clearance_m, settings.roomy_clearance_m) if roomy_wanted else (settings.clearance_m,)
        blocked, *wider = _blocked(states, occupied_fine, *(r / resolution for r in radii))
        low = (floor_z + settings.min_altitude_m - origin_[2]) / resolution - 0.5  # in layer-centre units
        high = (top_z - settings.ceiling_margin_m - origin_[2]) / resolution - 0.5
        k0 = max(math.ceil(low - _EPS), 0)
        k1 = max(min(math.floor(high + _EPS) + 1, states.shape[2]), k0)
        safe = _with_room_above((states == FREE) & ~blocked, body_cells) & ~_under_unknown(states, seen_cells)
        safe[:, :, :k0] = False
        safe[:, :, k1:] = False
        roomy = None
        if wider:
            roomy_cells = max(math.ceil((settings.body_height_m - settings.roomy_clearance_m) / resolution - _EPS), 0)
            roomy = _with_room_above((states == FREE) & ~wider[0], roomy_cells) & safe
        view = view if settings.gain_model == "view" else None
        return cls(origin_, float(resolution), states, safe, (k0, k1), settings, roomy, view)

    def reachable(self, position: Vec3) -> np.ndarray:
        """Bool mask of the safe cells 26-connected to the safe cell nearest `position`; all False if none."""
        mask = np.zeros(self._free.shape, dtype=bool)
        label = self._label_near(position)
        if label is not None:
            k0, k1 = self._band
            mask[:, :, k0:k1] = self._labels == label
        return mask

    def connected(self, a: Vec3, b: Vec3) -> bool:
        """The safe cells nearest `a` and `b` (as `reachable` takes them) are 26-connected through safe cells."""
        label = self._label_near(a)
        return label is not None and label == self._label_near(b)

    def in_pocket(self, position: Vec3) -> bool:
        """The space reachable from `position` is a pocket (under POCKET_M3, or none at all): a drone that stepped
        aside, or whose map grew round it, and that must get out before calling anything unreachable (from a
        pocket every plan fails after a few cells, and every frontier would be given up)."""
        label = self._label_near(position)
        return label is None or bool(self._component_sizes[label] * self.resolution**3 < POCKET_M3)

    def _label_near(self, position: Vec3) -> int | None:
        """The `_labels` component of the safe cell nearest `position` (within START_SEARCH_RADIUS_M), or None."""
        nearest = self.planning_grid.nearest_free(position, START_SEARCH_RADIUS_M)
        if nearest is None:
            return None
        i, j, k = self.planning_grid.indices_of(nearest[None, :])[0]
        return int(self._labels[i, j, k - self._band[0]])

    def escape(self, position: Vec3) -> Vec3 | None:
        """Centre of the safe cell nearest `position`, within ESCAPE_RADIUS_M, that is not in a pocket and is
        reached by a straight line through known FREE cells (the drone's own cell is FREE: `free_points`) with no
        OCCUPIED cell along the airframe's top; None."""
        big = self._component_sizes * self.resolution**3 >= POCKET_M3
        big[0] = False  # label 0: not safe
        k0, k1 = self._band
        mask = np.zeros(self._free.shape, dtype=bool)
        mask[:, :, k0:k1] = big[self._labels]
        p = np.asarray(position, dtype=float)
        lo = np.maximum(np.floor((p - ESCAPE_RADIUS_M - self.origin) / self.resolution), 0).astype(np.int64)
        hi = np.minimum(np.floor((p + ESCAPE_RADIUS_M - self.origin) / self.resolution) + 1, mask.shape)
        cells = np.argwhere(mask[lo[0] : int(hi[0]), lo[1] : int(hi[1]), lo[2] : int(hi[2])]) + lo
        if len(cells) == 0:
            return None
        centres = self._centre(cells)
        distance = np.linalg.norm(centres - p, axis=1)
        order = np.argsort(distance, kind="stable")
        order = order[distance[order] <= ESCAPE_RADIUS_M][:_ESCAPE_TRIES]
        # The way out is flown straight: at the drone's height only through cells the map knows to be FREE, and
        # with no obstacle the top of the airframe would meet. Above the drone it may be unknown: a camera that
        # looks ahead never sees the cone right above it (which is what makes a take-off spot a pocket).
        starts = np.repeat(p[None, :], len(order), axis=0)
        clear = self._segments_within(starts, centres[order], self._free)
        top = np.array([0.0, 0.0, self.settings.body_height_m])
        clear &= self._segments_within(starts + top, centres[order] + top, ~self._occupied)
        return _vec3(centres[order[np.argmax(clear)]]) if clear.any() else None

    def frontiers(self, position: Vec3, clock: StageClock = NO_CLOCK) -> list[Frontier]:
        """The frontier groups seen from `position`'s reachable space, by gain (the view gain when the grid has
        a camera, else the box gain), largest first; `clock` times the view gains (stage `view_gain`)."""
        reach = self.reachable(position)
        if not reach.any():
            return []
        offsets = _ball_offsets(self.settings.reach_m / self.resolution)
        nearest = _first_hit(reach, self._frontier_cells, offsets)
        cells = self._frontier_cells[nearest >= 0]
        if len(cells) == 0:
            return []
        viewpoints = cells + offsets[nearest[nearest >= 0]]
        group, counts = self._group(cells)
        points = _nearest_to_group_mean(cells, group, len(counts))
        gains = self.gain_at(self._centre(cells[points]))
        keep = np.flatnonzero((counts >= 2) & (gains >= self.settings.min_gain_m3))
        keep = keep[np.argsort(-gains[keep], kind="stable")]
        targets, eyes = self._centre(cells[points[keep]]), self._centre(viewpoints[points[keep]])
        seen = self._sees(eyes, targets)
        found = []
        for g, target, eye, ok in zip(keep, targets, eyes, seen):
            viewpoint = eye if ok else self._seeing_viewpoint(cells[points[g]], reach, offsets)
            if viewpoint is not None:
                found.append(Frontier(_vec3(target), _vec3(viewpoint), float(gains[g]), int(counts[g])))
        if self.view is None or not found:
            return found
        with clock.measure("view_gain"):
            gained = self._with_view_gains(found)
        worth = [f for f in gained if f.gain >= self.settings.min_view_gain_m3]
        return sorted(worth, key=lambda f: -f.gain)

    def _with_view_gains(self, found: list[Frontier]) -> list[Frontier]:
        """The frontiers with their view gains. A frontier whose viewpoint is its own point (a drone can stand
        in that frontier cell) gives the camera no direction: it is looked at towards the unknown around it (the
        middle of the open unknown cells in its gain cube) or, where that lies straight above or below, in the
        best of LOOK_YAWS directions; its point moves LOOK_AHEAD_M that way, so the flight, which faces the
        point, looks where the gain was counted. (Facing +x by default, such a spot at the take-off point counted
        the whole corridor ahead as its own.)"""
        eyes, points = np.array([f.viewpoint for f in found]), np.array([f.point for f in found])
        blind = np.flatnonzero(np.hypot(*(points - eyes)[:, :2].T) < self.resolution / 2)
        towards = self._unknown_direction(points[blind])
        level = np.hypot(towards[:, 0], towards[:, 1]) >= self.resolution / 2
        yaw = np.arctan2(towards[:, 1], towards[:, 0])
        if not level.all():
            yaw[~level] = self._best_heading(eyes[blind[~level]])
        points[blind] = eyes[blind] + LOOK_AHEAD_M * np.stack([np.cos(yaw), np.sin(yaw), 0 * yaw], axis=1)
        worth = self.view_gain(eyes, points)
        return [dataclasses.replace(f, point=_vec3(p), gain=float(w)) for f, p, w in zip(found, points, worth)]

    def _best_heading(self, eyes: np.ndarray) -> np.ndarray:
        """(N,) the best of LOOK_YAWS evenly spaced headings (radians) for the camera at each eye, by view gain."""
        headings = np.arange(LOOK_YAWS) * (2 * math.pi / LOOK_YAWS)
        ahead = np.stack([np.cos(headings), np.sin(headings), np.zeros(LOOK_YAWS)], axis=1)
        looks = (eyes[:, None, :] + ahead[None, :, :]).reshape(-1, 3)
        gains = self.view_gain(np.repeat(eyes, LOOK_YAWS, axis=0), looks).reshape(len(eyes), LOOK_YAWS)
        best: np.ndarray = headings[np.argmax(gains, axis=1)]
        return best

    def _unknown_direction(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) from each point to the middle of the open unknown cells in its gain cube (0 where none): the mean
        offset of those cells from the point's cell, gathered for every point at once from the unknown cells padded
        with the cube's half-width (outside the grid is not unknown)."""
        out = np.zeros((len(points), 3))
        half = round(self.settings.gain_radius_m / self.resolution)
        offsets = _cube_offsets(half)
        pad = 2 * half + 1
        padded = np.pad(self._unknown, pad)
        strides = np.array([padded.shape[1] * padded.shape[2], padded.shape[2], 1])
        cells = np.floor((np.asarray(points, dtype=float).reshape(-1, 3) - self.origin) / self.resolution)
        # a point whose cube misses the grid sees no unknown cell: it is moved to where its cube is all padding
        cells = np.clip(cells, -half - 1, np.array(self._unknown.shape) + half).astype(np.int64)
        base, flat_offsets, flat = (cells + pad) @ strides, offsets @ strides, padded.ravel()
        for start in range(0, len(cells), _DIRECTION_CHUNK):
            chunk = slice(start, start + _DIRECTION_CHUNK)
            found = flat[base[chunk, None] + flat_offsets[None, :]]  # (C, cube cells)
            counts = found.sum(axis=1)
            sums = found.astype(np.float64) @ offsets
            out[chunk] = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], 0.0) * self.resolution
        return out

    def viewpoint_for(
        self, point: Vec3, position: Vec3, keep_off: Vec3 | None = None, keep_off_m: float = 0.0
    ) -> Vec3 | None:
        """Where to look at `point` from: the nearest safe cell reachable from `position`, within reach_m of it,
        with a line of sight to it, and whose centre is `keep_off_m` or more from `keep_off` (a drone parked
        there); None if there is none (or the point is outside the grid)."""
        idx = np.floor((np.asarray(point, dtype=float) - self.origin) / self.resolution).astype(np.int64)
        if not np.all((idx >= 0) & (idx < np.array(self._free.shape))):
            return None
        reach = self.reachable(position)
        offsets = _ball_offsets(self.settings.reach_m / self.resolution)
        if keep_off is not None and keep_off_m > 0:
            centres = self._centre(idx + offsets)
            offsets = offsets[np.linalg.norm(centres - np.asarray(keep_off, dtype=float), axis=1) >= keep_off_m]
        seen_from = self._seeing_viewpoint(idx, reach, offsets)
        return None if seen_from is None else _vec3(seen_from)

    def gain_at(self, points: np.ndarray) -> np.ndarray:
        """(N,) unknown volume (m^3) in the gain cube around each (N, 3) world point; 0 outside the grid."""
        idx = np.floor((np.asarray(points, dtype=float).reshape(-1, 3) - self.origin) / self.resolution)
        shape = np.array(self._unknown.shape)
        inside = np.all((idx >= 0) & (idx < shape), axis=1)
        half = round(self.settings.gain_radius_m / self.resolution)
        lo = np.clip(idx[inside] - half, 0, shape).astype(np.int64).T
        hi = np.clip(idx[inside] + half + 1, 0, shape).astype(np.int64).T
        table = self._unknown_table
        total = np.zeros(len(lo[0]), dtype=np.int64)
        for corner in range(8):  # inclusion-exclusion over the 8 corners of each box
            pick = [(hi, lo)[(corner >> axis) & 1][axis] for axis in range(3)]
            sign = -1 if bin(corner).count("1") % 2 else 1
            total += sign * table[pick[0], pick[1], pick[2]]
        gains = np.zeros(len(idx))
        gains[inside] = total * self.resolution**3
        return gains

    def view_gain(self, viewpoints: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(N,) open unknown volume (m^3) the camera sees from each viewpoint turned (in yaw) to face its point:
        the integral of r^2 dr dOmega over the unknown stretches of rays cast through the frustum, each ray
        stopped at the first OCCUPIED cell or where it leaves the grid. 0 for every row without a camera."""
        eyes = np.asarray(viewpoints, dtype=float).reshape(-1, 3)
        if self.view is None or len(eyes) == 0:
            return np.zeros(len(eyes))
        looks = np.asarray(points, dtype=float).reshape(-1, 3) - eyes
        rays, solid = self.view.rays()
        gains: np.ndarray = self._ray_volumes(eyes, np.arctan2(looks[:, 1], looks[:, 0]), rays, solid).sum(axis=1)
        return gains

    def _ray_volumes(self, eyes: np.ndarray, yaws: np.ndarray, rays: np.ndarray, solid: np.ndarray) -> np.ndarray:
        """(N, rays) unknown volume along each ray from each eye, the rays (at yaw 0) turned by that eye's yaw.

        Rays are sampled once per cell length: a wall of whole cells is never stepped over (a ray crosses at
        least a cell's length of it), only the corner of a staircase of cells may leak a sample, which does not
        change a ranking. Each eye is taken at the centre of its cell and each yaw to the nearest of YAW_BINS
        headings (1 degree; the rays are VIEW_RAY_SPACING_DEG apart): the samples' cells are then fixed offsets
        from the eye's cell, computed once per heading and grid shape (`_ray_offsets`), and a candidate costs
        one gather instead of the floating-point walk of every sample (551 hall candidates: 23 ms against 108).
        """
        assert self.view is not None
        codes, strides = self._view_codes
        r = _ray_ranges(self.view, self.resolution)
        weight = (solid[:, None] * (r**2 * self.resolution)[None, :]).astype(np.float32)  # (rays, steps)
        inner = np.array(self._occupied.shape)
        cell = np.clip(np.floor((eyes - self.origin) / self.resolution), 0, inner - 1).astype(np.int64)
        base = (cell + self._view_pad) @ strides
        heading = np.round(np.mod(yaws, 2 * math.pi) / (2 * math.pi) * YAW_BINS).astype(np.int64) % YAW_BINS
        flat, last = codes.ravel(), codes.size - 1
        out = np.zeros((len(eyes), len(rays)))
        for start in range(0, len(eyes), _VIEW_CHUNK):
            chunk = slice(start, start + _VIEW_CHUNK)
            offsets = np.stack(
                [_ray_offsets(self.view, self.resolution, tuple(strides.tolist()), int(h)) for h in heading[chunk]]
            )
            # Past the first sample outside the grid (a padding cell: a stop) the index may leave the array;
            # clipped, what it reads there is never counted.
            found = flat[np.clip(base[chunk, None, None] + offsets, 0, last)]  # (C, rays, steps)
            stop = found == _VIEW_STOP  # each ray counts up to its first stop (argmax: a third cheaper than a scan)
            first = np.where(stop.any(axis=-1), stop.argmax(axis=-1), stop.shape[-1])
            seen = (found == _VIEW_UNKNOWN) & (np.arange(stop.shape[-1]) < first[..., None])
            out[chunk] = np.einsum("crs,rs->cr", seen.astype(np.float32), weight)
        return out

    @cached_property
    def _view_codes(self) -> tuple[np.ndarray, np.ndarray]:
        """What a view ray meets in each cell, padded with `_view_pad` stopping cells all round, and the padded
        grid's index strides."""
        codes = np.where(self._occupied, _VIEW_STOP, np.where(self._unknown, _VIEW_UNKNOWN, 0)).astype(np.uint8)
        codes = np.pad(codes, self._view_pad, constant_values=_VIEW_STOP)
        return codes, np.array([codes.shape[1] * codes.shape[2], codes.shape[2], 1], dtype=np.int64)

    @cached_property
    def _view_pad(self) -> int:
        """Stopping cells round the grid for the view rays: a ray's first sample (at the camera's min range) lands
        within them, and as later samples move at most a cell along each axis, the first sample to leave the grid
        lands on one of them."""
        assert self.view is not None
        return math.ceil(self.view.min_range_m / self.resolution) + 2

    def travel_distances(self, starts: np.ndarray, goals: np.ndarray) -> np.ndarray:
        """(S, G) metres a drone flies from each start to each goal through this map's safe cells (`TravelGraph`):
        at least the straight line, and the straight line where this map knows no way. A start is taken at the
        safe cell nearest it, as `reachable` does (a drone beside a wall sits in a cell its clearance blocks)."""
        starts = np.asarray(starts, dtype=float).reshape(-1, 3)
        nearest = [self.planning_grid.nearest_free(p, START_SEARCH_RADIUS_M) for p in starts]
        from_cells = np.array([p if n is None else n for p, n in zip(starts, nearest)]).reshape(-1, 3)
        nodes = self.travel_graph.node_of(from_cells)
        nodes[[n is None for n in nearest]] = -1
        return self.travel_graph.distances(starts, goals, start_nodes=nodes, limit_m=SEARCH_LIMIT_M)

    def travel_between(self, points: np.ndarray) -> np.ndarray:
        """(N, N) metres between safe points (viewpoints) through this map's safe cells, searched to
        SEARCH_LIMIT_M: beyond it, the straight line and at least the limit (`TravelGraph.distances`). A shorter
        search is cheaper (for 169 viewpoints of a generated building: 21 ms to 6 m, 68 ms to 15 m) but puts two
        viewpoints one above the other, 40 m apart by the stairs, 6 m apart: tours then hopped between storeys."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        return self.travel_graph.distances(points, points, limit_m=SEARCH_LIMIT_M)

    @cached_property
    def travel_graph(self) -> TravelGraph:
        return TravelGraph(~self.planning_grid.occupied, self.origin, self.resolution)

    def is_frontier_near(self, point: Vec3, radius: float) -> bool:
        """Some FREE cell bordering UNKNOWN lies within `radius` of `point`, reachable or not.

        No reach test: it tells whether the unknown space a target was chosen for is still unseen, whoever
        sees it.
        """
        centres = self._centre(self._frontier_cells)
        return bool(np.any(np.sum((centres - np.asarray(point, dtype=float)) ** 2, axis=1) <= radius**2))

    def unknown_fraction(self) -> float:
        """Share of the flight band's cells still unknown (0 when the band is empty)."""
        k0, k1 = self._band
        band = self._unknown[:, :, k0:k1]
        return float(band.mean()) if band.size else 0.0

    @cached_property
    def _labels(self) -> np.ndarray:
        """26-connected components of the safe cells, over the flight band's layers only (nothing else is safe)."""
        k0, k1 = self._band
        labels = _label_26(~self.planning_grid.occupied[:, :, k0:k1])
        return labels

    @cached_property
    def _not_occupied(self) -> np.ndarray:
        not_occupied: np.ndarray = ~self._occupied
        return not_occupied

    @cached_property
    def _component_sizes(self) -> np.ndarray:
        """Cells per label of `_labels` (label 0, the cells that are not safe, included)."""
        return np.bincount(self._labels.ravel())

    @cached_property
    def _frontier_cells(self) -> np.ndarray:
        """(n, 3) indices of the FREE cells 6-adjacent to an UNKNOWN cell, before the reach test."""
        unknown, near = self._unknown, np.zeros_like(self._unknown)
        for axis in range(3):
            lower, upper = (slice(None),) * axis + (slice(None, -1),), (slice(None),) * axis + (slice(1, None),)
            near[lower] |= unknown[upper]
            near[upper] |= unknown[lower]
        return np.argwhere(near & self._free)

    @cached_property
    def _unknown_table(self) -> np.ndarray:
        """Summed-volume table of the unknown cells, with a zero first plane on each axis."""
        table = np.zeros(tuple(n + 1 for n in self._unknown.shape), dtype=np.int32)
        inner = table[1:, 1:, 1:]
        np.cumsum(self._unknown, axis=2, dtype=np.int32, out=inner)  # in place: half the time of chained cumsums
        np.cumsum(inner, axis=1, out=inner)
        np.cumsum(inner, axis=0, out=inner)
        return table

    def _group(self, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Group id per cell (26-connected component x cluster bin) and the cell count per group."""
        lo, hi = cells.min(axis=0), cells.max(axis=0) + 1
        crop = np.zeros(tuple(hi - lo), dtype=bool)  # labelling only the frontier's bounding box is cheaper
        crop[tuple((cells - lo).T)] = True
        labels = _label_26(crop)
        component = labels[tuple((cells - lo).T)].astype(np.int64)
        bins = np.floor((cells + 0.5) * self.resolution / self.settings.cluster_size_m + _EPS).astype(np.int64)
        key = component
        for axis in range(3):
            key = key * (int(bins[:, axis].max()) + 1) + bins[:, axis]
        _, group, counts = np.unique(key, return_inverse=True, return_counts=True)
        return group.reshape(-1), counts

    def _seeing_viewpoint(self, cell: np.ndarray, reach: np.ndarray, offsets: np.ndarray) -> np.ndarray | None:
        """Centre of the nearest reachable cell within reach that has a line of sight to `cell`, or None."""
        candidates = cell + offsets
        candidates = candidates[np.all((candidates >= 0) & (candidates < reach.shape), axis=1)]
        candidates = candidates[reach[tuple(candidates.T)]]
        seeing = np.flatnonzero(self._sees(self._centre(candidates), self._centre(cell)))
        return self._centre(candidates[seeing[0]]) if len(seeing) else None

    def _sees(self, eyes: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """(M,) whether each segment from eyes (M, 3) to targets (M, 3 or 3,) crosses no OCCUPIED cell (sampled)."""
        return self._segments_within(eyes, targets, self._not_occupied)

    def _segments_within(self, eyes: np.ndarray, targets: np.ndarray, allowed: np.ndarray) -> np.ndarray:
        """(M,) whether every sample of each segment (every quarter cell) lies in an `allowed` cell."""
        if len(eyes) == 0:
            return np.zeros(0, dtype=bool)
        rays = np.broadcast_to(targets, eyes.shape) - eyes
        longest = float(np.max(np.linalg.norm(rays, axis=1)))
        steps = np.linspace(0.0, 1.0, max(2, math.ceil(longest / (self.resolution * _LINE_OF_SIGHT_STEP)) + 1))
        samples = eyes[:, None, :] + steps[None, :, None] * rays[:, None, :]
        idx = np.floor((samples - self.origin) / self.resolution).astype(np.int64)
        idx = np.clip(idx, 0, np.array(allowed.shape) - 1)  # both ends are in the grid; guard rounding
        within: np.ndarray = allowed[idx[..., 0], idx[..., 1], idx[..., 2]].all(axis=1)
        return within

    def _centre(self, idx: np.ndarray) -> np.ndarray:
        return self.origin + (np.asarray(idx, dtype=float) + 0.5) * self.resolution


def _ray_ranges(view: ViewModel, resolution: float) -> np.ndarray:
    """Distances of a view ray's samples from the eye: one per cell length, from the camera's min range."""
    return np.arange(view.min_range_m + resolution / 2, view.max_range_m, resolution)


@lru_cache(maxsize=YAW_BINS)
def _ray_offsets(view: ViewModel, resolution: float, strides: tuple[int, int, int], heading: int) -> np.ndarray:
    """(rays, steps) flat index offsets, in a grid of `strides`, from an eye's cell to the cell of each sample of
    each view ray, the camera turned to heading `heading` of YAW_BINS and the eye at its cell's centre."""
    rays, _ = view.rays()
    yaw = 2 * math.pi * heading / YAW_BINS
    cos, sin = math.cos(yaw), math.sin(yaw)
    direction = np.stack([rays[:, 0] * cos - rays[:, 1] * sin, rays[:, 0] * sin + rays[:, 1] * cos, rays[:, 2]], 1)
    steps = _ray_ranges(view, resolution) / resolution
    cells = np.floor(0.5 + steps[None, :, None] * direction[:, None, :]).astype(np.int64)  # from the eye's cell
    offsets: np.ndarray = (cells @ np.array(strides, dtype=np.int64)).astype(np.int32)  # 30 kB a heading
    return offsets


def _label_26(mask: np.ndarray) -> np.ndarray:
    """The 26-connected components of `mask`, numbered from 1 in raster order (0 elsewhere): `ndimage.label` with
    a 3x3x3 structure, label for label, from cc3d, 5-6 times faster (the hall's grid: 12.4 -> 2.1 ms). A view
    labels three masks: the unknown space (specks), the safe cells, and the frontier cells."""
    labels: np.ndarray = cc3d.connected_components(mask, connectivity=26)
    return labels


def _without_specks(unknown: np.ndarray, min_cells: int) -> np.ndarray:
    """`unknown` minus its 26-connected components of fewer than `min_cells` cells: specks of space the camera
    grazed but never quite covered, inside known space, which would keep a mission alive for nothing."""
    if min_cells <= 1 or not unknown.any():
        return unknown
    labels = _label_26(unknown)
    small = np.bincount(labels.ravel()) < min_cells
    small[0] = False
    kept: np.ndarray = unknown & ~small[labels]
    return kept


def _mark_free(
    states: np.ndarray, origin: np.ndarray, resolution: float, points: Sequence[Vec3], radius: float
) -> np.ndarray:
    """`states` with the UNKNOWN cells around each point (centre within `radius`, or holding it) made FREE."""
    if len(points) == 0:
        return states
    states = states.copy()
    shape = np.array(states.shape)
    offsets = _cube_offsets(math.ceil(radius / resolution) + 1)
    for p in np.asarray(points, dtype=float).reshape(-1, 3):
        if not np.all(np.isfinite(p)):
            continue
        home = np.floor((p - origin) / resolution).astype(np.int64)
        cells = home + offsets
        centres = origin + (cells + 0.5) * resolution
        near = (np.sum((centres - p) ** 2, axis=1) <= radius**2) | np.all(cells == home, axis=1)
        cells = cells[near & np.all((cells >= 0) & (cells < shape), axis=1)]
        hit = tuple(cells.T)
        states[hit] = np.where(states[hit] == UNKNOWN, np.uint8(FREE), states[hit])
    return states


def _blocked(states: np.ndarray, occupied_fine: np.ndarray | None, *radii_cells: float) -> list[np.ndarray]:
    """For each radius, the cells closer than it (in cells) to an obstacle: to an OCCUPIED cell, or, given the
    occupied voxels of a finer grid, to one of those (and to OCCUPIED cells with no occupied voxel: obstacles
    marked by hand). The radii share the fine grid's marking and packing."""
    occupied = states == OCCUPIED
    if occupied_fine is None:
        return _inflate_all(occupied, radii_cells)
    f = occupied_fine.shape[0] // max(states.shape[0], 1)
    if f < 1 or occupied_fine.shape != tuple(n * f for n in states.shape):
        raise ValueError(f"fine occupancy {occupied_fine.shape} is not an integer refinement of {states.shape}")
    marked = occupied & ~_coarsen(occupied_fine, f)
    if marked.any():
        occupied_fine = occupied_fine | marked.repeat(f, 0).repeat(f, 1).repeat(f, 2)
    return _inflate_all_coarsened(occupied_fine, tuple(r * f for r in radii_cells), f)


def _inflate_all_coarsened(occupied: np.ndarray, radii_cells: Sequence[float], f: int) -> list[np.ndarray]:
    """`[_coarsen(m, f) for m in _inflate_all(occupied, radii_cells)]` (each axis a multiple of f) without the
    fine masks: a coarse column ORs the dilation at its f x f fine columns, which is one dilation by the
    structuring element grown by those offsets, taken at every f-th column only (`_coarse_heights`): the ORs run
    over f^2 fewer words (the hall's fine grid at 0.1 m, two radii: 74 -> 36 ms on an idle core, the same masks)."""
    nx, ny, nz = occupied.shape
    if not occupied.any():
        return [_coarsen(occupied, f) for _ in radii_cells]
    if nz > _BITS:
        return [_coarsen(m, f) for m in _inflate_all(occupied, radii_cells)]
    column = _pack_columns(occupied)
    top = np.uint64((1 << nz) - 1) if nz < _BITS else np.uint64(np.iinfo(np.uint64).max)
    cx, cy = nx // f, ny // f
    out = []
    for radius_cells in radii_cells:
        if radius_cells <= 0:
            out.append(_coarsen(occupied, f))
            continue
        heights = _coarse_heights(radius_cells, f)
        pad = max(max(abs(ex), abs(ey)) for ex, ey in heights)
        runs = {h: np.pad(_run_bits(column, h) & top, pad) for h in set(heights.values())}
        grown = np.zeros((cx, cy), dtype=np.uint64)
        for (ex, ey), h in heights.items():  # coarse column X takes fine column f*X + e (zero beyond the grid)
            grown |= runs[h][pad + ex : pad + ex + f * cx : f, pad + ey : pad + ey + f * cy : f]
        fine_z = _unpack_columns(grown, nz)
        coarse = fine_z[:, :, 0::f].copy()
        for i in range(1, f):
            coarse |= fine_z[:, :, i::f]
        out.append(coarse)
    return out


@lru_cache(maxsize=16)
def _coarse_heights(radius_cells: float, f: int) -> dict[tuple[int, int], int]:
    """`_column_heights` grown by the f x f columns of a coarse cell: coarse column X, Y of the dilation coarsened
    by f is the OR of fine columns f*X + a - dx, f*Y + b - dy (a, b < f; dx, dy of the element), each dilated
    along z by the element's half-height there; per offset the largest half-height counts (runs only grow)."""
    grown: dict[tuple[int, int], int] = {}
    for (dx, dy), h in _column_heights(radius_cells).items():
        for a in range(f):
            for b in range(f):
                key = (a - dx, b - dy)
                grown[key] = max(grown.get(key, 0), h)
    return grown


def _coarsen(mask: np.ndarray, f: int) -> np.ndarray:
    """Cells of a grid f times coarser holding any True cell of `mask` (each axis a multiple of f)."""
    out = mask
    for axis in range(3):  # ORs of strided views: several times faster than .any() over a 6D reshape or np.take
        index: list[slice] = [slice(None)] * 3
        index[axis] = slice(0, None, f)
        coarser = out[tuple(index)].copy()
        for i in range(1, f):
            index[axis] = slice(i, None, f)
            coarser |= out[tuple(index)]
        out = coarser
    return out


def _under_unknown(states: np.ndarray, cells: int) -> np.ndarray:
    """Cells with an UNKNOWN cell among the `cells` cells above them (above the grid counts as unknown)."""
    unknown = np.concatenate([states == UNKNOWN, np.ones(states.shape[:2] + (cells,), dtype=bool)], axis=2)
    out = np.zeros(states.shape, dtype=bool)
    nz = states.shape[2]
    for j in range(1, cells + 1):
        out |= unknown[:, :, j : j + nz]
    return out


def _body_cells(body_height_m: float, resolution: float) -> int:
    """Cells above a position's cell whose clearance covers the point body_height_m above its centre."""
    return max(math.ceil((body_height_m - resolution / 2) / resolution - _EPS), 0)


def _with_room_above(clear: np.ndarray, cells: int) -> np.ndarray:
    """Cells that are clear together with the `cells` cells above them (the airframe's column)."""
    out = clear.copy()
    for j in range(1, cells + 1):
        out[:, :, :-j] &= clear[:, :, j:]
        out[:, :, -j:] = False
    return out


def _inflate(occupied: np.ndarray, radius_cells: float) -> np.ndarray:
    """`OccupancyGrid.inflate` without its distance transform: the cells whose cube comes closer than
    `radius_cells` to an occupied cube, i.e. occupied dilated by (ball of centre distance < radius) + 3x3x3."""
    return _inflate_all(occupied, (radius_cells,))[0]


def _inflate_all(occupied: np.ndarray, radii_cells: Sequence[float]) -> list[np.ndarray]:
    """`_inflate` for each radius. A column of at most 64 cells fits one integer: runs are shifts, and the x/y ORs
    touch nx*ny words instead of nx*ny*nz cells (what makes the 0.1 m obstacle test affordable), which is
    `_inflate_all_coarsened` at f = 1; taller columns dilate cell by cell along z."""
    nx, ny, nz = occupied.shape
    if nz <= _BITS or not occupied.any():
        return _inflate_all_coarsened(occupied, radii_cells, 1)
    out = []
    for radius_cells in radii_cells:
        if radius_cells <= 0:
            out.append(occupied.copy())
            continue
        heights = _column_heights(radius_cells)
        runs = {
            h: ndimage.maximum_filter1d(occupied.view(np.uint8), 2 * h + 1, axis=2, mode="constant").view(bool)
            for h in set(heights.values())
        }
        grown = np.zeros_like(occupied)
        for (dx, dy), h in heights.items():
            if abs(dx) < nx and abs(dy) < ny:
                grown[max(dx, 0) : nx + min(dx, 0), max(dy, 0) : ny + min(dy, 0)] |= runs[h][
                    max(-dx, 0) : nx - max(dx, 0), max(-dy, 0) : ny - max(dy, 0)
                ]
        out.append(grown)
    return out


@lru_cache(maxsize=16)
def _column_heights(radius_cells: float) -> dict[tuple[int, int], int]:
    """`_inflate`'s structuring element, (ball of centre distance < radius) + 3x3x3, as columns: every column
    (dx, dy) of it is a symmetric run of dz, given by its half-height. `_inflate` dilates along z once per run
    length, then ORs shifted copies in x and y: far cheaper than a 3D structuring element or a distance transform.
    Made once per radius (a decision inflates twice; building it took a tenth of the planning grid)."""
    ball = _ball_offsets(radius_cells - _EPS, strict=True)
    offsets = np.unique((ball[:, None, :] + _cube_offsets(1)[None, :, :]).reshape(-1, 3), axis=0)
    heights: dict[tuple[int, int], int] = {}
    for dx, dy, dz in offsets.tolist():
        heights[(dx, dy)] = max(heights.get((dx, dy), 0), abs(dz))
    return heights


def _pack_columns(mask: np.ndarray) -> np.ndarray:
    """(nx, ny, nz <= 64) bool -> (nx, ny) uint64, bit k set where mask[..., k]."""
    nx, ny, nz = mask.shape
    nbytes = -(-nz // 8)
    if nz % 8:  # whole bytes per column, so that the packing runs over one flat array (3x faster than by axis)
        whole = np.zeros((nx, ny, nbytes * 8), dtype=bool)
        whole[:, :, :nz] = mask
    else:
        whole = np.ascontiguousarray(mask, dtype=bool)
    packed = np.packbits(whole.reshape(-1), bitorder="little").reshape(nx, ny, nbytes)
    words = np.zeros((nx, ny, 8), dtype=np.uint8)
    words[:, :, :nbytes] = packed
    return words.view("<u8")[:, :, 0]


def _unpack_columns(words: np.ndarray, nz: int) -> np.ndarray:
    as_bytes = np.ascontiguousarray(words.astype("<u8")).view(np.uint8).reshape(words.shape + (8,))
    return np.unpackbits(as_bytes, axis=2, count=nz, bitorder="little").view(bool)


def _run_bits(column: np.ndarray, h: int) -> np.ndarray:
    """Each bit ORed with its h neighbours above and below (a 1D dilation along z, on packed columns)."""
    out = column.copy()
    for s in range(1, h + 1):
        shift = np.uint64(s)
        out |= (column << shift) | (column >> shift)
    return out


def _ball_offsets(radius_cells: float, strict: bool = False) -> np.ndarray:
    """(M, 3) integer offsets with length <= radius (< when strict), nearest first."""
    offsets = _cube_offsets(max(math.floor(radius_cells + _EPS), 0))
    length2 = np.sum(offsets**2, axis=1)
    keep = length2 < radius_cells**2 if strict else length2 <= radius_cells**2 + _EPS
    nearest_first: np.ndarray = offsets[keep][np.argsort(length2[keep], kind="stable")]
    return nearest_first


def _cube_offsets(half: int) -> np.ndarray:
    """(M, 3) every integer offset with no coordinate beyond `half`."""
    axis = np.arange(-half, half + 1)
    return np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)


def _first_hit(mask: np.ndarray, cells: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """For each cell, the index of the first offset (nearest, as `offsets` is sorted) landing on `mask`; -1 if none.

    Gathers at the frontier cells only, in chunks of growing size: most frontier cells are at distance 0 or 1
    from a reachable cell, so they are settled by the first chunks and leave the rest to the few far ones.
    """
    found = np.full(len(cells), -1, dtype=np.int64)
    pad = int(np.abs(offsets).max())
    padded = np.pad(mask, pad)
    strides = np.array([padded.shape[1] * padded.shape[2], padded.shape[2], 1])
    base = (cells + pad) @ strides
    flat_offsets, flat = offsets @ strides, padded.ravel()
    pending = np.arange(len(cells))
    start, size = 0, 1
    while start < len(offsets) and len(pending):
        hits = flat[base[pending, None] + flat_offsets[None, start : start + size]]
        hit = hits.any(axis=1)
        found[pending[hit]] = start + hits[hit].argmax(axis=1)
        pending = pending[~hit]
        start, size = start + size, size * 4
    return found


def _nearest_to_group_mean(cells: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:
    """(n_groups,) row in `cells` of each group's cell nearest to the group's mean."""
    counts = np.bincount(group, minlength=n_groups)
    sums = np.stack([np.bincount(group, weights=cells[:, a], minlength=n_groups) for a in range(3)], axis=1)
    mean = sums / np.maximum(counts, 1)[:, None]
    distance2 = np.sum((cells - mean[group]) ** 2, axis=1)
    order = np.lexsort((distance2, group))
    firsts = np.flatnonzero(np.r_[True, np.diff(group[order]) != 0])
    return order[firsts]


def _vec3(p: np.ndarray) -> Vec3:
    return float(p[0]), float(p[1]), float(p[2])
