"""The run's recording (`OUT/run.rrd`, Rerun): what the swarm did, on the mission clock, for a 3D timeline viewer.

One job: turn what the harness side already knows into Rerun entities. The observer logs what it hears on the
bus and the map it builds (`MissionRecording`); at the end `swarm run` adds what only the harness knows (faults,
link impairments, the agents' own counters from their summaries) with `add_report`, which merges it into the
same file. Agents never record here and never depend on Rerun: the recording is written by the observer and the
harness, who may know the world (DESIGN.md section 11).

Every file of a run carries the same application id and a run-wide recording id (`run_recording_id`), so
recordings written by other processes of the same run (per-agent ones, later) merge with it in the viewer.
Time is the "mission" timeline: seconds since the mission clock's zero (`report.json` `started_at`).

Entities (`/` is the world frame, z up, metres):

=================================  ==========================================================================
world                              the world mesh (static; simulated runs only)
map/tI_J_K                         the swarm's fused map (marching cubes) in `TILE_M` cubes; a refresh logs the
                                   tiles that changed (and clears emptied ones), every `MAP_PERIOD_S` or less
                                   often when large (`map_period_s`)
drones/K/pose                      the drone's pose (translation, yaw) and, under it, its body
drones/K/trajectory                the heartbeat positions so far, re-logged every `TRAIL_PERIOD_S`
drones/K/segment                   the straight segment the drone is flying (its heartbeat's `heading_to`)
drones/K/target                    the viewpoint its leader assigned it, and the line to the point it looks at
frontiers/K                        the frontier candidates drone K reported, coloured and tagged by gain
swarm/clusters                     the clusters (leader: members), as text, on each change
series/leader/K, series/...        time series: leader of each drone, explored fraction (swarm and per drone),
                                   patches held, bytes sent and received, frame rate
events                             joins and leaves, faults, link impairments and partitions, "done"
=================================  ==========================================================================

The observer logs from its asyncio thread and from its coverage thread: `RecordingStream` is thread-safe, and
its time cursor is per thread, so each log call sets the time it means just before it (`_at`).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from rerun.chunk import LazyChunkStream, RrdReader

from swarm.agent.summary import AgentSummary
from swarm.bus.holdings import DigestWire
from swarm.bus.messages import AgentState
from swarm.mission.files import MissionReport
from swarm.mission.rrd_files import BLUEPRINT_NAME, RECORDING_NAME
from swarm.patches.lattice import Lattice
from swarm.roles.messages import FrontierReport, TargetAssignment
from swarm.sensing.messages import depth_millimetres

APPLICATION_ID = "swarm"
TIMELINE = "mission"
MAP_PERIOD_S = 5.0
MAP_BYTES_PER_S = 150_000  # the file grows by at most this much per second from the map's changed tiles
MAP_CPU_SHARE = 0.05  # and the marching-cubes passes take at most this share of one core (0.45 s: office, full)
TILE_M = 2.0
TILE_GROWTH = 0.1  # between refreshes, a tile is logged again when its triangle count changed by this share
TILE_GROWTH_MIN = 20  # or at least this many: a surface refined in place (its vertices shift) is not logged again
TRAIL_PERIOD_S = 2.0
POSE_PERIOD_S = 0.2  # heartbeats come at 5 Hz or more; a viewer needs no more
DEPTH_PERIOD_S = 1.0  # a depth image a second per drone (38 kB each as millimetres): what a person scrubs past
BODY_HALF_SIZE = (0.25, 0.25, 0.06)
WORLD_RGBA = (200, 200, 200, 60)
MAP_RGB = (90, 160, 230, 150)  # translucent: the drones, targets and paths inside the map stay in view

Cluster = tuple[int, tuple[int, ...]]  # (leader, sorted member ids), as `swarm.mission.observer.clusters_of`

# Tableau 10: distinct on light and dark backgrounds; drone K gets PALETTE[(K - 1) % 10]
PALETTE: tuple[tuple[int, int, int], ...] = (
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
)


def open_stream(path: Path, recording_id: str, stream_to: str | None = None) -> rr.RecordingStream:
    """A recording stream of the run written to `path` and, with `stream_to` (a viewer's gRPC proxy URL,
    `rerun+http://HOST:PORT/proxy`), also sent live to that viewer."""
    stream = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
    if stream_to is None:
        stream.save(path)
    else:
        stream.set_sinks(rr.FileSink(path), rr.GrpcSink(stream_to))
    return stream


def run_blueprint() -> rrb.Blueprint:
    """The viewer's layout: the swarm in 3D (world, map, drones, frontiers; the agents' own maps and the depth
    cameras are there to switch on), and beside it the explored fraction, the clusters and the events."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(
                name="swarm",
                origin="/",
                contents=["+ /world", "+ /map/**", "+ /drones/**", "+ /frontiers/**", "- /drones/*/camera/**"],
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(name="explored", origin="/series/explored"),
                rrb.TextDocumentView(name="clusters", origin="/swarm/clusters"),
                rrb.TextLogView(name="events", origin="/events"),
                row_shares=[2, 1, 2],
            ),
            column_shares=[3, 1],
        ),
        rrb.TimePanel(timeline=TIMELINE, play_state="following"),  # live: the newest; a finished run: its end
        collapse_panels=True,
    )


def drone_color(drone: int) -> tuple[int, int, int]:
    return PALETTE[(drone - 1) % len(PALETTE)]


def patches_held(holdings: DigestWire) -> int:
    """How many patch ids a holdings digest names (its ranges are inclusive)."""
    return sum(hi - lo + 1 for entry in holdings.entries for lo, hi in entry.ranges)


def yaw_quaternion(yaw_deg: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation by `yaw_deg` about +z (the world frame's up)."""
    half = math.radians(yaw_deg) / 2.0
    return (0.0, 0.0, math.sin(half), math.cos(half))


def gain_colors(gains: np.ndarray) -> np.ndarray:
    """(N, 3) uint8: low gain blue to high gain red, scaled to the largest gain of the set (all blue when every
    gain is 0 or the set is empty)."""
    g = np.asarray(gains, dtype=np.float64).reshape(-1)
    top = float(g.max()) if g.size else 0.0
    share = np.clip(g / top, 0.0, 1.0) if top > 0 else np.zeros_like(g)
    low, high = np.array([40, 90, 255], dtype=np.float64), np.array([255, 40, 40], dtype=np.float64)
    return (low + share[:, None] * (high - low)).round().astype(np.uint8)


def map_period_s(written_bytes: int, mesh_cpu_s: float) -> float:
    """How long until the next map refresh after one that wrote `written_bytes` and whose mesh took `mesh_cpu_s`
    of CPU: `MAP_PERIOD_S`, or longer, so the map adds at most `MAP_BYTES_PER_S` to the file and
    `MAP_CPU_SHARE` of a core to the observer."""
    return max(MAP_PERIOD_S, written_bytes / MAP_BYTES_PER_S, mesh_cpu_s / MAP_CPU_SHARE)


Tile = tuple[int, int, int]


def map_tiles(
    vertices: np.ndarray, triangles: np.ndarray, tile_m: float = TILE_M
) -> dict[Tile, tuple[np.ndarray, np.ndarray]]:
    """The mesh cut into cubes of `tile_m` (world-aligned, by triangle centroid): per tile its own vertices
    (float32) and triangles indexing them (uint32)."""
    vertices = np.asarray(vertices, dtype=np.float32).reshape(-1, 3)
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if len(triangles) == 0:
        return {}
    keys = np.floor(vertices[triangles].mean(axis=1) / tile_m).astype(np.int64)
    order = np.lexsort(keys.T[::-1])
    keys, triangles = keys[order], triangles[order]
    starts = np.flatnonzero(np.r_[True, np.any(keys[1:] != keys[:-1], axis=1)])
    tiles = {}
    for start, stop in zip(starts, np.r_[starts[1:], len(keys)]):
        used, local = np.unique(triangles[start:stop], return_inverse=True)
        i, j, k = (int(c) for c in keys[start])
        tiles[(i, j, k)] = (vertices[used], local.reshape(-1, 3).astype(np.uint32))
    return tiles


def _tile_ranges(keys: np.ndarray, lattice: Lattice, tile_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Per block key, the first and last tile its world extent widened by one voxel reaches into."""
    corner = lattice.origin_array + np.asarray(keys, dtype=np.float64) * lattice.block_size
    lo = np.floor((corner - lattice.voxel_size) / tile_m).astype(np.int64)
    hi = np.floor((corner + lattice.block_size + lattice.voxel_size) / tile_m).astype(np.int64)
    return lo, hi


def tiles_near_blocks(keys: np.ndarray, lattice: Lattice, tile_m: float = TILE_M) -> set[Tile]:
    """The tiles the blocks `keys` reach into, widened by a voxel: where the surface can change when those
    blocks change (a voxel's change moves only triangles within one voxel of it)."""
    keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    if len(keys) == 0:
        return set()
    lo, hi = _tile_ranges(keys, lattice, tile_m)
    tiles: set[Tile] = set()
    for a, b in np.unique(np.hstack([lo, hi]), axis=0).reshape(-1, 2, 3):
        for i in range(a[0], b[0] + 1):
            for j in range(a[1], b[1] + 1):
                for k in range(a[2], b[2] + 1):
                    tiles.add((i, j, k))
    return tiles


def blocks_in_tiles(keys: np.ndarray, tiles: set[Tile], lattice: Lattice, tile_m: float = TILE_M) -> np.ndarray:
    """The rows of (M,3) block `keys` that reach into one of `tiles`, widened by a voxel: every block the surface
    inside those tiles is made from (a triangle's corners are voxels within one voxel of it)."""
    keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    if len(keys) == 0 or not tiles:
        return np.zeros((0, 3), dtype=np.int32)
    lo, hi = _tile_ranges(keys, lattice, tile_m)
    wanted = np.array(sorted(tiles), dtype=np.int64)
    hit = np.zeros(len(keys), dtype=bool)
    for tile in wanted:  # a few dozen tiles at most: a patch reaches the camera's range
        hit |= np.all((lo <= tile) & (tile <= hi), axis=1)
    return keys[hit].astype(np.int32)


def tile_fingerprint(vertices: np.ndarray, triangles: np.ndarray) -> tuple[int, int, float]:
    """What a tile holds, independent of vertex and triangle order: counts and the sum of its corners (to the
    micrometre); equal for the same surface extracted again from an unchanged part of the map."""
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(triangles, dtype=np.int64)]
    return len(vertices), len(triangles), round(float(corners.sum()), 6)


def tile_grew(logged: int | None, now: int) -> bool:
    """Whether a tile with `now` triangles, logged with `logged` (None: never), changed enough to log again."""
    return logged is None or abs(now - logged) > max(TILE_GROWTH_MIN, TILE_GROWTH * logged)


def tile_path(tile: Tile, root: str = "map") -> str:
    i, j, k = tile
    return f"{root}/t{i}_{j}_{k}"


class MapTiles:
    """A map's surface logged as `TILE_M` tiles under `root`: each refresh logs only the tiles that changed since
    they were last logged (`tile_grew`; with `exact`, every tile that differs at all) and clears emptied ones."""

    def __init__(self, stream: rr.RecordingStream, root: str = "map") -> None:
        self.stream = stream
        self.root = root
        self._tiles: dict[Tile, tuple[int, int, float]] = {}

    def log(
        self, vertices: np.ndarray, triangles: np.ndarray, exact: bool = False, only: set[Tile] | None = None
    ) -> int:
        """Log the surface at the stream's current time; returns the bytes written (vertices and indices).
        `only`: the surface given is that of these tiles alone (a partial mesh); the other tiles keep theirs."""
        tiles = map_tiles(vertices, triangles)
        if only is not None:
            tiles = {tile: mesh for tile, mesh in tiles.items() if tile in only}
        written = 0
        for tile, (tile_vertices, tile_triangles) in sorted(tiles.items()):
            fingerprint = tile_fingerprint(tile_vertices, tile_triangles)
            logged = self._tiles.get(tile)
            if logged == fingerprint or not (exact or tile_grew(logged[1] if logged else None, len(tile_triangles))):
                continue
            self._tiles[tile] = fingerprint
            self.stream.log(
                tile_path(tile, self.root),
                rr.Mesh3D(vertex_positions=tile_vertices, triangle_indices=tile_triangles, albedo_factor=MAP_RGB),
            )
            written += tile_vertices.nbytes + tile_triangles.nbytes
        for tile in sorted(set(self._tiles) - set(tiles)):
            if only is not None and tile not in only:
                continue
            del self._tiles[tile]
            self.stream.log(tile_path(tile, self.root), rr.Clear(recursive=False))
        return written


def cluster_text(clusters: Sequence[Cluster]) -> str:
    """One line per cluster, "leader 1: 1, 2, 3"; "no cluster" when every drone is silent or landed."""
    if not clusters:
        return "no cluster"
    return "\n".join(f"leader {leader}: {', '.join(str(m) for m in members)}" for leader, members in clusters)


class Throttle:
    """Per key, let one event through every `period_s` (the first one always)."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self._last: dict[int, float] = {}

    def ready(self, key: int, t: float) -> bool:
        last = self._last.get(key)
        if last is not None and t - last < self.period_s:
            return False
        self._last[key] = t
        return True


@dataclass(frozen=True)
class Event:
    t: float  # mission clock, seconds
    level: str  # a Rerun TextLog level: "INFO", "WARN", "ERROR"
    text: str


def report_events(report: MissionReport) -> list[Event]:
    """The events only the harness knows, from the report: each fault action, link impairment and partition,
    and the mission's end; sorted by time."""
    events = []
    for fault in report.faults:
        for action in fault.get("actions", []):
            text = f"fault {fault.get('fault')}: {action.get('step')}: {action.get('result', '')}".rstrip(": ")
            events.append(Event(float(action["t"]), "WARN", text))
    for imp in report.impairments:
        events.append(Event(float(imp["t"]), "WARN", f"link {imp.get('link')}: {imp.get('profile')}"))
    for part in report.partitions:
        components = " | ".join(",".join(str(k) for k in c) for c in part.get("components", []))
        events.append(Event(float(part["start"]), "ERROR", f"partition: {components}"))
        if part.get("end") is not None:
            events.append(Event(float(part["end"]), "INFO", f"partition healed: {components}"))
    level = "INFO" if report.status == "complete" else "ERROR"
    events.append(Event(report.duration_s, level, f"mission {report.status}: {report.reason}"))
    return sorted(events, key=lambda e: e.t)


class MissionRecording:
    """A run's recording, written to a file as it goes (headless: no viewer is started or needed)."""

    def __init__(self, path: Path, recording_id: str, stream_to: str | None = None) -> None:
        self.path = path
        self.recording_id = recording_id
        self.stream = open_stream(path, recording_id, stream_to)
        self.stream.send_blueprint(run_blueprint())
        self.stream.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self._poses = Throttle(POSE_PERIOD_S)
        self._trails = Throttle(TRAIL_PERIOD_S)
        self._trail: dict[int, list[tuple[float, float, float]]] = {}
        self._lock = threading.Lock()  # the trails: heartbeats and the final flush come from different threads
        self._last_map_t: float | None = None
        self._map_period_s = MAP_PERIOD_S
        self._map_version: int | None = None
        self._map = MapTiles(self.stream)

    def _at(self, t: float) -> None:
        self.stream.set_time(TIMELINE, duration=max(0.0, t))

    def world(self, vertices: np.ndarray, triangles: np.ndarray) -> None:
        """The world mesh, static (the harness's truth; agents never see it)."""
        self.stream.log(
            "world",
            rr.Mesh3D(
                vertex_positions=np.asarray(vertices, dtype=np.float32),
                triangle_indices=np.asarray(triangles, dtype=np.uint32),
                albedo_factor=WORLD_RGBA,
            ),
            static=True,
        )

    def map_due(self, t: float, version: int) -> bool:
        """Whether to log the map at t: its `version` (e.g. patches fused) changed and the refresh period passed."""
        if version == self._map_version:
            return False
        return self._last_map_t is None or t - self._last_map_t >= self._map_period_s

    def map(
        self,
        t: float,
        vertices: np.ndarray,
        triangles: np.ndarray,
        version: int = 0,
        mesh_cpu_s: float = 0.0,
        exact: bool = False,
    ) -> int:
        """The fused map's surface at t: the tiles that grew or shrank since they were last logged (`tile_grew`;
        with `exact`, every tile that differs at all, so the last refresh is the final map), and a Clear for tiles
        that are empty now; `mesh_cpu_s`, what extracting the mesh cost, sets the next refresh with this call's
        own cost (`map_period_s`). Returns the bytes written (vertices and indices)."""
        started = time.thread_time()
        self._last_map_t, self._map_version = t, version
        self._at(t)
        written = self._map.log(vertices, triangles, exact)
        self._map_period_s = map_period_s(written, mesh_cpu_s + time.thread_time() - started)
        return written

    def state(self, t: float, state: AgentState, has_position: bool = True) -> None:
        """A heartbeat: leader and patches held always; pose, trajectory and segment once the drone has a
        position (thinned to `POSE_PERIOD_S` per drone)."""
        k = state.id
        if not self._poses.ready(k, t):
            return
        self._at(t)
        self.stream.log(f"series/leader/{k}", rr.Scalars(float(state.leader)))
        self.stream.log(f"series/patches_held/{k}", rr.Scalars(float(patches_held(state.holdings))))
        if not has_position:
            return
        x, y, z = (float(c) for c in state.position)
        position = (x, y, z)
        self.stream.log(
            f"drones/{k}/pose",
            rr.Transform3D(translation=position, quaternion=rr.Quaternion(xyzw=yaw_quaternion(state.yaw_deg))),
        )
        self.stream.log(
            f"drones/{k}/pose/body",
            rr.Boxes3D(
                half_sizes=[BODY_HALF_SIZE],
                colors=[drone_color(state.leader)],  # the cluster's colour: its leader's
                labels=[f"{k} {state.role} (leader {state.leader}) {state.phase}"],
            ),
        )
        if state.heading_to is not None:
            segment = [position, tuple(float(c) for c in state.heading_to)]
            self.stream.log(f"drones/{k}/segment", rr.LineStrips3D([segment], colors=[drone_color(k)]))
        else:
            self.stream.log(f"drones/{k}/segment", rr.Clear(recursive=False))
        with self._lock:
            self._trail.setdefault(k, []).append(position)
            if self._trails.ready(k, t):
                self._log_trail(k)

    def _log_trail(self, k: int) -> None:
        trail = self._trail.get(k, [])
        if len(trail) >= 2:
            self.stream.log(f"drones/{k}/trajectory", rr.LineStrips3D([trail], colors=[drone_color(k)]))

    def frontiers(self, t: float, report: FrontierReport) -> None:
        """The candidates drone K reported to its leader: frontier points, coloured and tagged by gain."""
        self._at(t)
        points = np.asarray(report.points, dtype=np.float32).reshape(-1, 3)
        gains = np.asarray(report.gains, dtype=np.float32).reshape(-1)
        if len(points) == 0 or len(points) != len(gains):
            self.stream.log(f"frontiers/{report.id}", rr.Clear(recursive=False))
            return
        self.stream.log(
            f"frontiers/{report.id}",
            rr.Points3D(points, colors=gain_colors(gains), radii=0.06),
            rr.AnyValues(gain=gains),
        )

    def targets(self, t: float, assignment: TargetAssignment) -> None:
        """A leader's assignment: each drone's target viewpoint and the point it is to look at."""
        self._at(t)
        if assignment.done:
            self.stream.log("events", rr.TextLog(f"leader {assignment.leader}: exploration done", level="INFO"))
            return
        for drone in assignment.drones:
            target = assignment.target_of(drone)
            if target is None:
                continue
            viewpoint, point = target
            self.stream.log(
                f"drones/{drone}/target",
                rr.Points3D([viewpoint], colors=[drone_color(drone)], radii=0.12, labels=[f"target of {drone}"]),
                rr.LineStrips3D([[viewpoint, point]], colors=[drone_color(drone)]),
            )

    def clusters(self, t: float, clusters: Sequence[Cluster]) -> None:
        self._at(t)
        self.stream.log("swarm/clusters", rr.TextDocument(cluster_text(clusters)))

    def explored(self, t: float, fraction: float, by_drone: Mapping[int, float]) -> None:
        self._at(t)
        self.stream.log("series/explored/swarm", rr.Scalars(fraction))
        for k, share in sorted(by_drone.items()):
            self.stream.log(f"series/explored/{k}", rr.Scalars(share))

    def event(self, t: float, text: str, level: str = "INFO") -> None:
        self._at(t)
        self.stream.log("events", rr.TextLog(text, level=level))

    def close(self) -> None:
        """Log every trail in full once more and write the file out."""
        with self._lock:
            for k in sorted(self._trail):
                self._log_trail(k)
        self.stream.flush()
        self.stream.disconnect()


class DepthRecording:
    """Each drone's depth image under its camera's pose (`drones/K/camera`: the camera-to-world transform and its
    pinhole; `drones/K/camera/depth`, millimetres), once every `period_s` per drone, from the camera driver
    (`swarm cameras --record`, mission.view_depth). `since`: the mission clock's zero (unix time)."""

    def __init__(
        self,
        path: Path,
        recording_id: str,
        since: float,
        K: np.ndarray,
        resolution: tuple[int, int],
        stream_to: str | None = None,
        period_s: float = DEPTH_PERIOD_S,
    ) -> None:
        self.stream = open_stream(path, recording_id, stream_to)
        self.since = since
        self.K = np.asarray(K, dtype=np.float64)
        self.resolution = resolution
        self._throttle = Throttle(period_s)
        self._lock = threading.Lock()

    def frame(self, drone: int, stamp: float, T_world_cam: np.ndarray, depth_m: np.ndarray) -> None:
        """A rendered frame: the drone's camera pose (optical frame, 4x4) and its depth in metres (0: none)."""
        t = stamp - self.since
        if not self._throttle.ready(drone, t):
            return
        millimetres = depth_millimetres(depth_m)
        with self._lock:
            self.stream.set_time(TIMELINE, duration=max(0.0, t))
            self.stream.log(
                f"drones/{drone}/camera",
                rr.Transform3D(mat3x3=T_world_cam[:3, :3], translation=T_world_cam[:3, 3]),
                rr.Pinhole(image_from_camera=self.K, resolution=self.resolution, camera_xyz=rr.ViewCoordinates.RDF),
            )
            self.stream.log(f"drones/{drone}/camera/depth", rr.DepthImage(millimetres, meter=1000.0))

    def close(self) -> None:
        self.stream.flush()
        self.stream.disconnect()


def summary_series(stream: rr.RecordingStream, summaries: Mapping[int, AgentSummary]) -> None:
    """Each agent's own counters, from its summary: bytes sent and received once a second, its frame rate."""
    for k, summary in sorted(summaries.items()):
        for t, sent, received in summary.timeline:
            stream.set_time(TIMELINE, duration=max(0.0, t))
            stream.log(f"series/bytes_sent/{k}", rr.Scalars(float(sent)))
            stream.log(f"series/bytes_received/{k}", rr.Scalars(float(received)))
        stream.set_time(TIMELINE, duration=max(0.0, summary.duration_s))
        stream.log(f"series/frame_rate_hz/{k}", rr.Scalars(summary.frame_rate_hz))


def add_report(
    out: Path,
    recording_id: str,
    report: MissionReport,
    summaries: Mapping[int, AgentSummary],
    stream_to: str | None = None,
) -> Path:
    """Add the harness's part (report events, the agents' counters) to OUT/run.rrd, merged with what the
    observer recorded (or alone, when the observer wrote none), and to the live viewer at `stream_to`.
    Returns the recording's path."""
    path = out / RECORDING_NAME
    part = out / f".{RECORDING_NAME}.harness"
    stream = open_stream(part, recording_id, stream_to)
    for event in report_events(report):
        stream.set_time(TIMELINE, duration=max(0.0, event.t))
        stream.log("events", rr.TextLog(event.text, level=event.level))
    summary_series(stream, summaries)
    stream.flush()
    stream.disconnect()
    run_blueprint().save(APPLICATION_ID, out / BLUEPRINT_NAME)  # the merge below keeps recordings only
    if not path.exists():
        part.replace(path)
        return path
    merged = out / f".{RECORDING_NAME}.merged"
    LazyChunkStream.merge(RrdReader(path).stream(), RrdReader(part).stream()).write_rrd(
        merged, application_id=APPLICATION_ID, recording_id=recording_id
    )
    merged.replace(path)
    part.unlink()
    return path


@dataclass(frozen=True)
class EntitySpan:
    """What a recording holds at one entity path: rows, and the mission-time range they cover (None: static)."""

    rows: int
    first_s: float | None
    last_s: float | None


def entity_spans(paths: Iterable[Path]) -> dict[str, EntitySpan]:
    """Read recordings back through Rerun's own reader: every entity path with its rows and mission-time range."""
    spans: dict[str, EntitySpan] = {}
    for path in paths:
        for chunk in RrdReader(path).stream():
            batch = chunk.to_record_batch()
            rows, first, last = chunk.num_rows, None, None
            if TIMELINE in batch.schema.names:
                ns = [v for v in batch.column(TIMELINE).cast("int64").to_pylist() if v is not None]
                if ns:
                    first, last = min(ns) / 1e9, max(ns) / 1e9
            old = spans.get(chunk.entity_path)
            if old is not None:
                rows += old.rows
                first = _min(first, old.first_s)
                last = _max(last, old.last_s)
            spans[chunk.entity_path] = EntitySpan(rows, first, last)
    return spans


def _min(a: float | None, b: float | None) -> float | None:
    return b if a is None else a if b is None else min(a, b)


def _max(a: float | None, b: float | None) -> float | None:
    return b if a is None else a if b is None else max(a, b)


def entity_rows(paths: Iterable[Path], entity: str, component: str) -> list[tuple[float, list[Any]]]:
    """Every row of `component` (e.g. "Transform3D:translation") logged at `entity` ("/drones/1/pose") on the
    mission timeline, as (mission seconds, the row's values), in time order."""
    rows: list[tuple[float, list[Any]]] = []
    for path in paths:
        for chunk in RrdReader(path).stream():
            if chunk.entity_path != entity:
                continue
            batch = chunk.to_record_batch()
            if TIMELINE not in batch.schema.names or component not in batch.schema.names:
                continue
            times = batch.column(TIMELINE).cast("int64").to_pylist()
            for ns, value in zip(times, batch.column(component).to_pylist()):
                if ns is not None and value is not None:
                    rows.append((ns / 1e9, value))
    return sorted(rows, key=lambda row: row[0])


def recording_ids(path: Path) -> list[str]:
    """The recording ids in an .rrd file."""
    return [entry.recording_id for entry in RrdReader(path).recordings()]
