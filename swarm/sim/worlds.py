"""Worlds: z-up triangle meshes in metres (x east, y north, z up), with the geometric queries the simulator needs.

A world is a built-in layout (`layouts.LAYOUTS`), a generated building (`gen:SEED[:options]`, `buildings.py`) or a
mesh file (.ply/.obj/.stl).
Queries run on a cached Open3D `RaycastingScene`. "Inside a solid" is decided by ray parity and is only
meaningful for closed meshes (every edge shared by exactly two triangles, as the built-in box worlds are); for an
open mesh nothing is inside, and only the distance to its surface counts.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import open3d as o3d

from swarm.config import Box, MissionSettings, Vec3
from swarm.errors import WorldError
from swarm.patches.backend import tensor
from swarm.sim import buildings, layouts

MESH_EXTENSIONS = (".ply", ".obj", ".stl")
MAX_WORLD_SIZE_M = 1000.0
_BOX_SHRINK = 5e-4  # keeps touching boxes from sharing faces, so ray parity stays exact
_PARITY_SAMPLES = 3  # odd number of rays per inside test: robust to rays grazing an edge
_SMALL_QUERY = 64  # below this many points, one thread is faster than a thread pool


@dataclass(eq=False)
class World:
    name: str
    vertices: np.ndarray  # (V,3) float64
    triangles: np.ndarray  # (F,3) int32
    default_start: Vec3
    _scene: o3d.t.geometry.RaycastingScene | None = field(default=None, init=False, repr=False)
    _closed: bool | None = field(default=None, init=False, repr=False)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    @property
    def scene(self) -> o3d.t.geometry.RaycastingScene:
        """The Open3D ray-casting scene of the mesh (built once), also for sensors that cast rays."""
        if self._scene is None:
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(tensor(self.vertices.astype(np.float32)), tensor(self.triangles.astype(np.uint32)))
            self._scene = scene
        return self._scene

    @property
    def closed(self) -> bool:
        """True when every edge is shared by exactly two triangles (inside/outside is well defined)."""
        if self._closed is None:
            edges = np.sort(self.triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
            _, counts = np.unique(edges, axis=0, return_counts=True)
            self._closed = bool(np.all(counts == 2))
        return self._closed

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Unsigned distance (m) of (N,3) points to the mesh surface."""
        pts = _as_points(points)
        return self.scene.compute_distance(_tensor(pts), nthreads=_threads(pts)).numpy().astype(np.float64)

    def is_inside_solid(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: the point is inside a closed solid (wall, rack, slab...). Always False for open meshes."""
        pts = _as_points(points)
        if not self.closed or len(pts) == 0:
            return np.zeros(len(pts), dtype=bool)
        occ = self.scene.compute_occupancy(_tensor(pts), nthreads=_threads(pts), nsamples=_PARITY_SAMPLES)
        return occ.numpy() > 0.5

    def floor_below(self, points: np.ndarray, max_drop: float = math.inf) -> np.ndarray:
        """(N,) z of the first surface straight below each point (NaN when there is none within max_drop)."""
        pts = _as_points(points)
        rays = np.zeros((len(pts), 6), dtype=np.float32)
        rays[:, :3] = pts
        rays[:, 5] = -1.0
        hit = self.scene.cast_rays(_tensor(rays), nthreads=_threads(pts))["t_hit"].numpy().astype(np.float64)
        hit[hit > max_drop] = np.inf
        return np.where(np.isfinite(hit), pts[:, 2] - hit, np.nan)

    def ceiling_above(self, points: np.ndarray) -> np.ndarray:
        """(N,) z of the first surface straight above each point (inf when there is none)."""
        pts = _as_points(points)
        rays = np.zeros((len(pts), 6), dtype=np.float32)
        rays[:, :3] = pts
        rays[:, 5] = 1.0
        hit = self.scene.cast_rays(_tensor(rays), nthreads=_threads(pts))["t_hit"].numpy().astype(np.float64)
        return pts[:, 2] + hit

    def line_of_sight(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(N,) bool: the segments a[i] -> b[i] cross no surface."""
        a, b = _as_points(a), _as_points(b)
        rays = np.hstack([a, b - a]).astype(np.float32)  # t_hit is then a fraction of the segment
        hit = self.scene.cast_rays(_tensor(rays), nthreads=_threads(a))["t_hit"].numpy()
        return ~(hit < 1.0)

    def occupancy(
        self, resolution: float, lo: np.ndarray | None = None, hi: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Ground-truth occupancy over [lo, hi): (origin of cell (0,0,0)'s corner, bool (nx,ny,nz)).

        A cell is occupied when its centre is inside a solid or closer to a surface than half its diagonal.
        """
        if resolution <= 0:
            raise ValueError("resolution must be positive")
        b_lo, b_hi = self.bounds
        lo = b_lo if lo is None else np.asarray(lo, dtype=np.float64)
        hi = b_hi if hi is None else np.asarray(hi, dtype=np.float64)
        shape = np.maximum(np.ceil((hi - lo) / resolution - 1e-9).astype(int), 0)
        axes = [lo[i] + (np.arange(shape[i]) + 0.5) * resolution for i in range(3)]
        centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        if len(centres) == 0:
            return lo, np.zeros(shape, dtype=bool)
        near = self.distance(centres) < resolution * 0.5 * math.sqrt(3.0)
        if self.closed:
            far = ~near
            near[far] = self.is_inside_solid(centres[far])
        return lo, near.reshape(shape)

    def save(self, path: str | Path) -> None:
        """Write the mesh as .ply/.obj/.stl (by extension)."""
        path = Path(path)
        if path.suffix.lower() not in MESH_EXTENSIONS:
            raise WorldError(f"cannot save world as '{path.suffix}': use one of {', '.join(MESH_EXTENSIONS)}")
        mesh = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(self.vertices), o3d.utility.Vector3iVector(self.triangles)
        )
        mesh.compute_triangle_normals()  # STL stores them
        if not o3d.io.write_triangle_mesh(path, mesh):
            raise WorldError(f"cannot write world mesh to {path}")


def _as_points(points: np.ndarray) -> np.ndarray:
    return np.asarray(points, dtype=np.float64).reshape(-1, 3)


def _tensor(a: np.ndarray) -> o3d.core.Tensor:
    return tensor(np.ascontiguousarray(a, dtype=np.float32))


def _threads(points: np.ndarray) -> int:
    return 1 if len(points) <= _SMALL_QUERY else 0


# --- built-in worlds -------------------------------------------------------------------------------------------

_UNIT_BOX = o3d.geometry.TriangleMesh.create_box()
_UNIT_VERTICES = np.asarray(_UNIT_BOX.vertices)
_UNIT_TRIANGLES = np.asarray(_UNIT_BOX.triangles)


def boxes_to_mesh(boxes: list[layouts.AxisBox], exact: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of closed boxes; every box after the first `exact` ones shrinks by half a mm."""
    lo = np.array([b[0] for b in boxes], dtype=np.float64)
    hi = np.array([b[1] for b in boxes], dtype=np.float64)
    lo[exact:] += _BOX_SHRINK
    hi[exact:] -= _BOX_SHRINK
    vertices = lo[:, None, :] + _UNIT_VERTICES[None, :, :] * (hi - lo)[:, None, :]
    triangles = _UNIT_TRIANGLES[None, :, :] + 8 * np.arange(len(boxes))[:, None, None]
    return vertices.reshape(-1, 3), triangles.reshape(-1, 3).astype(np.int32)


def world_from_layout(lay: layouts.BuildingLayout) -> World:
    vertices, triangles = boxes_to_mesh(lay.boxes)  # the floor slab is added first and stays exact
    return World(lay.name, vertices, triangles, lay.default_start)


def _from_layout(make: Callable[[], layouts.BuildingLayout]) -> Callable[[], World]:
    def build() -> World:
        return world_from_layout(make())

    build.__doc__ = make.__doc__
    return build


BUILTIN_WORLDS: dict[str, Callable[[], World]] = {name: _from_layout(f) for name, f in layouts.LAYOUTS.items()}


# --- loading ---------------------------------------------------------------------------------------------------


def is_mesh_file(spec: str) -> bool:
    """The world spec names a mesh file (not a built-in world or a generated building)."""
    return spec not in BUILTIN_WORLDS and not buildings.is_spec(spec)


def load_world(spec: str) -> World:
    """A built-in world by name, a generated building (`gen:SEED[:options]`, see `buildings`) or a .ply/.obj/.stl
    mesh file; raise WorldError (one line) when unusable."""
    if spec in BUILTIN_WORLDS:
        return BUILTIN_WORLDS[spec]()
    if buildings.is_spec(spec):
        return world_from_layout(buildings.layout_from_spec(spec))
    path = Path(spec)
    names = ", ".join(BUILTIN_WORLDS)
    if not path.exists():
        if path.suffix.lower() in MESH_EXTENSIONS or os.sep in spec:
            raise WorldError(f"world file {path} does not exist (built-in worlds: {names})")
        raise WorldError(
            f"world '{spec}' is neither a built-in world ({names}), a generated one ({buildings.SPEC_HELP}) "
            "nor an existing mesh file"
        )
    if path.suffix.lower() not in MESH_EXTENSIONS:
        raise WorldError(f"world file {path} has unsupported extension '{path.suffix}' (use .ply, .obj or .stl)")
    try:
        with path.open("rb") as f:
            head = f.read(3)
    except OSError as exc:
        raise WorldError(f"world file {path} cannot be read: {exc.strerror or exc}") from None
    if path.suffix.lower() == ".ply" and head != b"ply":
        raise WorldError(f"world file {path} is not a PLY file")  # checked here: the PLY reader prints to stderr
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh = o3d.io.read_triangle_mesh(path)
    mesh.remove_duplicated_vertices()  # STL stores three vertices per triangle
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    triangles = np.asarray(mesh.triangles, dtype=np.int32)
    if len(triangles) == 0 or len(vertices) == 0:
        raise WorldError(f"world file {path} holds no triangles (unreadable or empty mesh)")
    if not np.all(np.isfinite(vertices)):
        raise WorldError(f"world file {path} has non-finite vertex coordinates")
    extent = vertices.max(axis=0) - vertices.min(axis=0)
    if np.any(extent > MAX_WORLD_SIZE_M):
        raise WorldError(
            f"world file {path} is {extent.max():.0f} m across, over the {MAX_WORLD_SIZE_M:.0f} m limit "
            "(is it in millimetres?)"
        )
    world = World(path.stem, vertices, triangles, (0.0, 0.0, 0.0))
    world.default_start = find_default_start(world)
    return world


def world_command(spec: str, out: Path | None) -> int:
    """`swarm world SPEC [--out FILE]`: load or generate the world, print what it is, write its mesh."""
    if out is not None and out.suffix.lower() not in MESH_EXTENSIONS:
        raise WorldError(f"cannot save world as '{out.suffix}': use one of {', '.join(MESH_EXTENSIONS)}")
    started = time.perf_counter()
    world = load_world(spec)
    built_s = time.perf_counter() - started
    lo, hi = world.bounds
    size = hi - lo
    floors = floor_levels(world)
    x, y, z = world.default_start
    print(
        f"world {world.name}: {size[0]:.1f} x {size[1]:.1f} x {size[2]:.1f} m, "
        f"{len(floors)} {'storey' if len(floors) == 1 else 'storeys'} (floors at z "
        f"{', '.join(f'{f:g}' for f in floors) or '?'} m), start ({x:g}, {y:g}, {z:g}), {len(world.triangles)} "
        f"triangles, {'closed' if world.closed else 'open'}, loaded in {built_s:.2f} s"
    )
    if out is not None:
        world.save(out)
        print(f"wrote {out} (load it back with --world {out})")
    return 0


def find_default_start(world: World, clearance: float = 0.5, column_height: float = 2.0) -> Vec3:
    """A free floor point for a mesh without a declared start.

    Candidates are the points of a grid (0.5 m, at most 200 x 200) over the bounds, taken in order of distance
    to the bounds' centre. For each, a ray is cast straight down from 1 m above the mesh's lowest point (or from
    just above the top of a flat mesh); the first surface hit is that candidate's floor. The first candidate whose
    cast point is not inside a solid and whose column (floor to floor + column_height) keeps `clearance` from
    every surface but its own floor wins.
    """
    lo, hi = world.bounds
    extent = hi - lo
    step = max(0.5, float(max(extent[0], extent[1])) / 200.0)
    xs = np.arange(lo[0] + step / 2, hi[0], step) if extent[0] > step else np.array([(lo[0] + hi[0]) / 2])
    ys = np.arange(lo[1] + step / 2, hi[1], step) if extent[1] > step else np.array([(lo[1] + hi[1]) / 2])
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
    centre = (lo[:2] + hi[:2]) / 2
    xy = xy[np.lexsort((xy[:, 1], xy[:, 0], np.linalg.norm(xy - centre, axis=1)))]
    cast_z = lo[2] + min(1.0, float(extent[2])) + 0.01
    cast = np.column_stack([xy, np.full(len(xy), cast_z)])
    floor = world.floor_below(cast)
    ok = np.isfinite(floor) & ~world.is_inside_solid(cast)
    feet = np.column_stack([xy, floor])
    ok[ok] = _columns_clear(world, feet[ok], clearance, column_height)
    if not ok.any():
        raise WorldError(f"world '{world.name}' has no free floor point with {clearance} m clearance")
    x, y, z = feet[np.argmax(ok)]
    return float(x), float(y), _mm(z)


def floor_levels(world: World, min_share: float = 0.25) -> list[float]:
    """Heights (m) of the world's floors: levels where upward-facing surfaces cover at least `min_share` of the
    footprint, less the top of the roof (within 0.5 m of the mesh's top). An estimate for any mesh; exact for
    box worlds, whose slabs are the only such surfaces."""
    corners = world.vertices[world.triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area = np.linalg.norm(normals, axis=1) / 2
    up = (normals[:, 2] > 0.99 * np.maximum(np.linalg.norm(normals, axis=1), 1e-12)) & (area > 0)
    lo, hi = world.bounds
    footprint = float((hi[0] - lo[0]) * (hi[1] - lo[1]))
    levels = np.round(corners[up, :, 2].mean(axis=1) / 0.05) * 0.05
    floors: list[float] = []
    for level in np.unique(levels):
        if level < hi[2] - 0.5 and area[up][levels == level].sum() >= min_share * footprint:
            floors.append(round(float(level), 2) + 0.0)
    return floors


# --- spawn points ----------------------------------------------------------------------------------------------

_FLOOR_TOLERANCE_M = 0.25  # a spawn point's floor may differ this much from the start's floor
_LOS_HEIGHT_M = 1.0  # spawn points must be in sight of the start at this height (same room)


def _columns_clear(world: World, feet: np.ndarray, clearance: float, column_height: float) -> np.ndarray:
    """(N,) bool: the vertical column above each foot point keeps `clearance` from every surface but its floor.

    The column is sampled every clearance/2 m; at height h the floor itself is h away, so a sample only needs
    min(clearance, h) of free space.
    """
    if len(feet) == 0:
        return np.zeros(0, dtype=bool)
    heights = np.arange(0.05, column_height + 1e-9, max(clearance / 2, 0.05))
    heights = np.append(heights, column_height)
    pts = feet[:, None, :] + np.array([[0.0, 0.0, h] for h in heights])[None, :, :]
    dist = world.distance(pts.reshape(-1, 3)).reshape(len(feet), len(heights))
    need = np.minimum(clearance, heights)[None, :] - 1e-3
    return np.all(dist >= need, axis=1)


def spawn_points(
    world: World, start: Vec3 | None, n: int, spacing: float, clearance: float = 0.5, column_height: float = 2.0
) -> list[Vec3]:
    """n take-off points >= spacing apart around `start`, each standing on the floor with a clear column.

    Candidates lie on a square grid of pitch `spacing` centred on start, in order of distance to start (ties
    broken by angle); a candidate is kept when its floor is at the start's floor height, its column is clear and
    it is in sight of the start at 1 m above the floor. Deterministic.
    """
    if n < 1:
        raise ValueError("n must be at least 1")
    sx, sy, sz = start if start is not None else world.default_start
    label = f"start point ({sx:g}, {sy:g}, {sz:g})"
    lo, hi = world.bounds
    if not (np.all(np.array([sx, sy, sz]) >= lo) and np.all(np.array([sx, sy, sz]) <= hi)):
        raise WorldError(f"{label} is outside the world bounds {_fmt(lo)} - {_fmt(hi)}")
    probe = np.array([[sx, sy, sz + 0.1]])
    if world.is_inside_solid(probe)[0]:
        raise WorldError(f"{label} is inside a wall or another solid")
    floor_z = world.floor_below(probe)[0]
    if not np.isfinite(floor_z):
        raise WorldError(f"{label} has no floor below it")

    rings = math.ceil(math.sqrt(n)) + 5
    idx = np.arange(-rings, rings + 1)
    gi, gj = np.meshgrid(idx, idx, indexing="ij")
    offsets = np.stack([gi.ravel(), gj.ravel()], axis=1) * spacing
    radius, angle = np.linalg.norm(offsets, axis=1), np.arctan2(offsets[:, 1], offsets[:, 0])
    order = np.lexsort((angle.round(9), radius.round(9)))
    offsets = offsets[order][radius[order] <= rings * spacing + 1e-9]

    xy = np.array([sx, sy]) + offsets
    cast = np.column_stack([xy, np.full(len(xy), floor_z + 0.1)])
    inside_xy = np.all((xy >= lo[:2]) & (xy <= hi[:2]), axis=1)
    floors = world.floor_below(cast, max_drop=0.1 + _FLOOR_TOLERANCE_M)
    ok = inside_xy & np.isfinite(floors) & ~world.is_inside_solid(cast)
    ok &= np.abs(np.nan_to_num(floors, nan=np.inf) - floor_z) <= _FLOOR_TOLERANCE_M
    feet = np.column_stack([xy, np.where(ok, floors, floor_z)])
    ok[ok] = _columns_clear(world, feet[ok], clearance, column_height)
    eye = np.array([0.0, 0.0, _LOS_HEIGHT_M])
    start_eye = np.array([sx, sy, floor_z]) + eye
    ok[ok] = world.line_of_sight(np.repeat(start_eye[None], ok.sum(), axis=0), feet[ok] + eye)
    chosen = feet[ok][:n]
    if len(chosen) < n:
        raise WorldError(
            f"only {len(chosen)} of {n} take-off points with {spacing:g} m spacing and {clearance:g} m clearance "
            f"fit around {label}"
        )
    return [(float(x), float(y), _mm(z)) for x, y, z in chosen]


def _mm(z: float) -> float:
    """Round a ray-cast height (float32) to 0.1 mm, so a floor at 0 reads 0.0."""
    return float(np.round(z, 4)) + 0.0


def _fmt(v: np.ndarray) -> str:
    return "(" + ", ".join(f"{c:.1f}" for c in v) + ")"


def mission_volume(world: World | None, volume: Box | None) -> tuple[np.ndarray, np.ndarray]:
    """The mission volume (lo, hi): the configured box, else the world mesh's bounds."""
    if volume is not None:
        return np.array(volume.min, dtype=float), np.array(volume.max, dtype=float)
    if world is None:
        raise ValueError("no mission volume configured and no world to take its bounds from")
    return world.bounds


def mission_time_limit_s(mission: MissionSettings, world: World | None = None) -> float:
    """`mission.max_time_s`, or when unset the default for the mission's volume and drones (`world`: the
    mission's world, loaded when not given and needed)."""
    if mission.max_time_s is not None:
        return mission.max_time_s
    lo, hi = mission_volume(world or load_world(mission.world), mission.volume)
    return mission.time_limit_s(float(np.prod(hi - lo)))
