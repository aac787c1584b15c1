"""The agent's mapping task: the camera's depth frames, integrated into the open patch, sealed into patches.

Integration runs in one dedicated worker thread (the TSDF is never touched from two threads, and the event loop
stays free for flight and heartbeats). Frames are integrated only while the drone is airborne. The thread takes
the newest frame the source holds; one that was superseded before it was taken is counted (`not_taken`), so a
loaded machine lowers the frame rate instead of building a queue.

Every sealed patch goes to the private store and to the agent's fused map, to `on_sealed` (the patch sync, which
pushes it), and, when the agent has an output directory, to `<out_dir>/patches/<id>.patch` in the wire format
(the mission observer's referee view of what was mapped), and with `agent.state_dir` there too, durably (fsynced:
`swarm.files.write_durable`): an agent started again reloads its own patches of earlier runs from it (`recover`).
A patch that cannot be stored (a full disk, EIO, a read-only file system) is logged (`patch_store_failed`) and
counted by errno (`patch_store_failures`), and is pushed and fused all the same: the disk is a backup of the
map, never a condition of it. Patches received from peers are decoded,
validated
and fused in the same worker thread (`receive`). At the end the open patch is sealed too, so nothing seen is
lost, and the agent writes its own fused mesh.

A decision (`explore_view`) takes the map's occupancy grids in the mapping thread (kept and updated from what
changed: `swarm.patches.fused`), then builds the planning grid and the frontiers from that copy in a decision
thread of its own: measured with 5 drones in the office, those took 85 ms and 43 ms of the mapping thread's time
per decision at the median, during which no frame was integrated.

For the bandwidth report the task also measures, once per `explore.loop_s`, what sending its whole fused
map would cost (`FusedMap.wire_size`): the whole-map baseline patch sharing is compared with.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import errno
import os
import resource
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import psutil

from swarm.agent.autopilot import TelemetryCache
from swarm.agent.sensing import DepthFrame, StreamSource
from swarm.aio import wait_event
from swarm.config import SwarmConfig, Vec3
from swarm.errors import SwarmError
from swarm.explore.frontiers import ExplorationGrid, Frontier, ViewModel
from swarm.files import TEMP_SUFFIX, write_atomic, write_durable
from swarm.patches.fused import OCCUPIED, compressed_size
from swarm.patches.mapper import Mapper
from swarm.patches.patch import Patch, PatchId
from swarm.patches.sealer import patch_block_limit
from swarm.patches.signing import Signing
from swarm.patches.wire import PatchDecodeError
from swarm.sensing.peers import PeerSighting, mask_peers
from swarm.stages import NO_CLOCK, StageClock

SealedCallback = Callable[[PatchId, bytes], None]
STREAM_WAIT_S = 0.2  # a stream source is polled this often for the stop event when no frame comes
MIN_HEIGHT_M = 0.3  # below this the camera mostly sees the floor it stands on
CAMERA_SILENT_S = 3.0  # in the air this long without a frame from the stream: logged (the map has stopped growing)
DECISION_NICENESS = 5  # the decision thread runs this much nicer than the mapping thread (`_yield_to_frames`)
BASELINE_SAMPLE_LOOPS = 20  # the whole-map baseline is measured every this many exploration loops


@dataclasses.dataclass
class Recovery:
    """What `recover_patches` found in the state directory."""

    patches: list[tuple[PatchId, bytes]] = dataclasses.field(default_factory=list)  # own, earlier epochs, fused
    rejected: dict[str, int] = dataclasses.field(default_factory=dict)  # files that are no usable patch, by reason
    stale_temp: int = 0  # temp files of writes a crash interrupted, removed


def recover_patches(state_dir: Path, mapper: Mapper, max_bytes: int) -> Recovery:
    """Fuse the patches of `mapper`'s producer from earlier epochs kept in `state_dir`. A file is rejected, by
    reason, when its name is no patch id ("name"), it is empty ("empty_file": what a power cut can leave of a file
    written without fsync), larger than `max_bytes` ("too_large", not read), unreadable ("unreadable"), or its
    bytes are not that patch (the decoder's reason: a file cut short fails its msgpack or its checksum).

    Never raises for what is in the directory. Hidden temp files of other processes (a write that a crash
    interrupted) are removed: a patch file only ever appears whole, by rename, so they hold nothing stored."""
    found = Recovery()

    def reject(reason: str) -> None:
        found.rejected[reason] = found.rejected.get(reason, 0) + 1

    own_temp = f".{os.getpid()}{TEMP_SUFFIX}"
    for path in _listing(state_dir, f".*{TEMP_SUFFIX}"):
        if not path.name.endswith(own_temp):
            with contextlib.suppress(OSError):
                path.unlink()
                found.stale_temp += 1
    for path in _listing(state_dir, "*.patch"):
        try:
            pid = PatchId.parse(path.stem)
        except ValueError:
            reject("name")
            continue
        if pid.producer != mapper.producer or pid.epoch == mapper.epoch or mapper.holds(pid):
            continue
        try:
            if path.stat().st_size > max_bytes:
                reject("too_large")
                continue
            data = path.read_bytes()
        except OSError:
            reject("unreadable")
            continue
        if not data:
            reject("empty_file")
            continue
        try:
            mapper.receive_wire(data, pid, max_bytes)
        except PatchDecodeError as exc:
            reject(exc.reason)
            continue
        found.patches.append((pid, data))
    return found


def _listing(directory: Path, pattern: str) -> list[Path]:
    """The directory's entries matching `pattern`, sorted; none when it cannot be listed (it is logged when the
    first patch fails to be stored there)."""
    try:
        return sorted(directory.glob(pattern))
    except OSError:
        return []


class MappingTask:
    def __init__(
        self,
        config: SwarmConfig,
        epoch: int,
        source: StreamSource,
        bounds: tuple[np.ndarray, np.ndarray],
        log: Callable[..., None],
        out_dir: Path | None,
        on_sealed: SealedCallback | None = None,
        peers: Callable[[], list[PeerSighting]] = list,
        signing: Signing | None = None,
        clock: StageClock = NO_CLOCK,
    ) -> None:
        self.config = config
        self.clock = clock  # stage costs (swarm.stages): integrate, store_patch, fuse_patch, occupancy, ...
        self.bounds = bounds
        self.source = source
        self.log = log
        self.mapper = Mapper(
            config.mapping,
            config.agent.id,
            epoch,
            bounds,
            known_weight=config.mapping.known_weight,
            max_blocks=patch_block_limit(config.mapping, config.camera),
            signing=signing,
        )
        self.patches_dir = out_dir / "patches" if out_dir is not None else None
        if self.patches_dir is not None:
            self.patches_dir.mkdir(parents=True, exist_ok=True)
        self.state_dir = config.agent.state_dir
        self.store_failures: dict[str, int] = {}  # errno name -> patch files not stored
        if self.state_dir is not None:
            try:
                self.state_dir.mkdir(parents=True, exist_ok=True)
            except OSError as exc:  # a read-only or full disk: map on, every store will fail and be counted
                self.log("state_dir_failed", state_dir=str(self.state_dir), errno=errno_name(exc), error=str(exc))
        self.out_dir = out_dir
        self.frames = 0
        self.frames_skipped = 0
        self.airborne_s = 0.0  # time spent airborne with the camera running: what frame_rate_hz divides by
        self.patches_sealed = 0
        self.busy_s = 0.0
        self.patches_received = 0
        self.baseline_bytes = 0  # sum of the whole map's wire size, once per baseline loop
        self.baseline_loops = 0
        self.on_sealed = on_sealed
        self.stream_counters: dict[str, int] | None = None  # a stream source's, at the end
        self.peers = peers  # the other drones' last heartbeats (called on the event loop)
        self.pixels_masked = 0
        self.camera_silences = 0  # times the stream went silent for CAMERA_SILENT_S in the air
        self._rss_at_start = psutil.Process().memory_info().rss  # the imports, mostly (Open3D alone ~104 MB)
        self.memory_mb: dict[str, float] = {}  # filled in at close (`_measure_memory`)
        self._worker = ThreadPoolExecutor(1, thread_name_prefix="mapping")
        # the planning grid and frontiers are built from an occupancy snapshot on their own thread, so that a
        # decision holds the mapping thread (and the camera's frames) only while the snapshot is taken
        self._decider = ThreadPoolExecutor(1, thread_name_prefix="decision", initializer=_yield_to_frames)

    def _integrate(self, frame: DepthFrame, started: float) -> None:
        self.frames += 1
        with self.clock.measure("integrate"):  # the open patch's TSDF, and sealing when this frame triggers it
            sealed = self.mapper.integrate(
                frame.depth, frame.K, frame.T_world_cam, frame.t, self.config.camera.max_range_m
            )
        if sealed is not None:
            with self.clock.measure("store_patch"):
                self._keep(sealed)
        self.busy_s += time.perf_counter() - started

    async def start(self) -> None:
        """Start the camera's stream, in the mapping thread, before the agent opens anything else or flies: a
        source that cannot start (no rclpy, a bag without depth, a sensor session that cannot open) is a
        SwarmError of one line, whatever the source raised, and the task is left closed. A drone does not take off
        without its camera: it would fly on and map nothing."""
        try:
            await asyncio.get_running_loop().run_in_executor(self._worker, self.source.start)
        except Exception as exc:
            await self.abandon()
            if isinstance(exc, SwarmError):
                raise
            reason = " ".join(f"{type(exc).__name__}: {exc}".split())
            raise SwarmError(f'camera.source = "{self.config.camera.source}" cannot start: {reason}') from exc

    async def abandon(self) -> None:
        """Close the source and stop the worker: the agent stops before its flight began (nothing was mapped)."""
        # a half-started source is closed as well as it can be: the error that stopped the agent is the one to report
        with contextlib.suppress(Exception):
            await asyncio.get_running_loop().run_in_executor(self._worker, self.source.close)
        self._worker.shutdown(wait=False)
        self._decider.shutdown(wait=False)

    async def run(self, telemetry: TelemetryCache, home_z: Callable[[], float | None], stop: asyncio.Event) -> None:
        """Frames as the camera publishes them, from a source `start` started: the newest one not taken yet,
        integrated while airborne (one the mapping thread was too busy to take is counted by the source as not
        taken: `frames_skipped`)."""
        source = self.source
        loop = asyncio.get_running_loop()
        last_frame, silent = time.monotonic(), False
        try:
            while not stop.is_set():
                base = home_z()
                airborne = base is not None and telemetry.samples > 0 and telemetry.position[2] - base > MIN_HEIGHT_M
                step_started = time.monotonic()
                came = await loop.run_in_executor(self._worker, self._step_stream, source, airborne, self.peers())
                now = time.monotonic()
                if airborne:
                    self.airborne_s += now - step_started
                if came or not airborne:
                    if silent and came:
                        self.log("camera_back", silent_s=round(now - last_frame, 1))
                    last_frame, silent = now, False
                elif not silent and now - last_frame > CAMERA_SILENT_S:
                    silent = True
                    self.camera_silences += 1
                    self.log("camera_silent", s=CAMERA_SILENT_S, counters=source.counters())
        finally:
            self.stream_counters = source.counters()
            self.frames_skipped += self.stream_counters.get("not_taken", 0)
            await loop.run_in_executor(None, source.close)

    def _step_stream(self, source: StreamSource, airborne: bool, peers: list[PeerSighting]) -> bool:
        """Integrate the newest frame when airborne, the peers masked where they were when it was taken; whether
        one came."""
        frame = source.wait_frame(STREAM_WAIT_S)
        if frame is None or not airborne:
            return frame is not None
        started = time.perf_counter()
        radius = self.config.camera.peer_mask_m
        if peers and radius > 0:
            centre = np.array([0.0, 0.0, self.config.explore.body_height_m / 2])
            centres = [p.at(frame.t) + centre for p in peers]
            with self.clock.measure("mask_peers"):
                depth, masked = mask_peers(frame.depth, frame.K, frame.T_world_cam, centres, radius)
            if masked:
                self.pixels_masked += masked
                frame = dataclasses.replace(frame, depth=depth)
        self._integrate(frame, started)
        return True

    def _keep(self, patch: Patch) -> None:
        self.patches_sealed += 1
        self.log("patch_sealed", patch=str(patch.id), blocks=patch.block_count, frames=patch.span.frames)
        data = self.mapper.data(patch.id)
        assert data is not None  # a sealed patch is in the private store
        if self.patches_dir is not None:  # the harness's view, read while the run lasts: atomic is enough
            self._store(patch.id, self.patches_dir, data, durable=False)
        if self.state_dir is not None:  # read back after a restart, maybe after a power cut
            self._store(patch.id, self.state_dir, data, durable=True)
        if self.on_sealed is not None:
            self.on_sealed(patch.id, data)

    def _store(self, pid: PatchId, directory: Path, data: bytes, durable: bool) -> None:
        """Write a sealed patch's file; a failure is logged and counted, never raised (the patch is fused and
        will be pushed whatever the disk does)."""
        try:
            (write_durable if durable else write_atomic)(directory / f"{pid}.patch", data)
        except OSError as exc:
            name = errno_name(exc)
            self.store_failures[name] = self.store_failures.get(name, 0) + 1
            self.log("patch_store_failed", patch=str(pid), errno=name, dir=str(directory), error=str(exc))

    async def recover(self) -> Recovery:
        """This drone's patches from earlier runs in `agent.state_dir`, fused into the map (`recover_patches`)."""
        if self.state_dir is None or not self.state_dir.is_dir():
            return Recovery()
        return await asyncio.get_running_loop().run_in_executor(
            self._worker, recover_patches, self.state_dir, self.mapper, self.config.mapping.max_patch_bytes
        )

    async def receive(self, data: bytes, pid: PatchId) -> None:
        """Decode, validate and fuse a peer's patch (the sync's sink); PatchDecodeError if unusable."""
        await asyncio.get_running_loop().run_in_executor(self._worker, self._receive, data, pid)

    def _receive(self, data: bytes, pid: PatchId) -> None:
        with self.clock.measure("fuse_patch"):  # decode, validate (signature included) and fuse
            received = self.mapper.receive_wire(data, pid, self.config.mapping.max_patch_bytes)
        if received:
            self.patches_received += 1

    async def explore_view(
        self, floor_z: float, top_z: float, position: Vec3, obstacles: Sequence[Vec3] = ()
    ) -> tuple[ExplorationGrid, list[Frontier]]:
        """The exploration grid of the current map (the open patch included: what we saw a moment ago counts)
        and its frontiers as seen from `position`. The occupancy snapshot is taken in the mapping thread, which
        owns the map; the grid and frontiers are built from it in the decision thread, while frames go on.
        `obstacles` are points the camera cannot see but must be avoided (a drone whose agent died in the air)."""
        loop = asyncio.get_running_loop()
        snapshot = await loop.run_in_executor(self._worker, self._occupancy)
        view = self._explore_view
        return await loop.run_in_executor(self._decider, view, snapshot, floor_z, top_z, position, obstacles)

    def _occupancy(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(origin, planning-grid states, occupied voxels or None) of the map now: copies the caller owns."""
        resolution, voxel = self.config.mapping.planning_resolution_m, self.config.mapping.voxel_size_m
        refine = round(resolution / voxel)
        occupied_fine = None
        with self.clock.measure("occupancy"), self.mapper.current_map() as fused:
            origin, states = fused.occupancy_grid(resolution, min_known=self.config.explore.seen_fraction)
            if refine > 1 and abs(refine * voxel - resolution) < 1e-9:
                top = origin + np.array(states.shape) * resolution
                occupied_fine = fused.occupancy_grid(voxel, origin, top)[1] == OCCUPIED
        return origin, states, occupied_fine

    def _explore_view(
        self,
        snapshot: tuple[np.ndarray, np.ndarray, np.ndarray | None],
        floor_z: float,
        top_z: float,
        position: Vec3,
        obstacles: Sequence[Vec3],
    ) -> tuple[ExplorationGrid, list[Frontier]]:
        origin, states, occupied_fine = snapshot
        resolution = self.config.mapping.planning_resolution_m
        for point in obstacles:
            _mark_occupied(states, origin, resolution, point, self.config.sim.drone_radius_m)
        with self.clock.measure("planning_grid"):
            grid = ExplorationGrid.from_states(
                origin,
                resolution,
                states,
                self.config.explore,
                floor_z,
                top_z,
                free_points=[position],
                occupied_fine=occupied_fine,
                view=ViewModel.from_camera(self.config.camera),
            )
        with self.clock.measure("frontiers"):  # view gains included (also timed alone: view_gain)
            return grid, grid.frontiers(position, self.clock)

    async def measure_baseline(self, stop: asyncio.Event) -> None:
        """Add up, once per exploration loop, what sending the whole fused map would cost, until `stop`.

        The map's wire size is measured after 1, 2, 4, 8, 16, 32 loops, then every `BASELINE_SAMPLE_LOOPS` loops
        (`baseline_interval`: a map grows fastest at first), not every loop: a measurement
        compresses the whole map (office, 5 drones on 2 cores: 0.14 s at the median; the hall: 2 s), and the
        baseline is a figure for the report, not something the drone needs. The map's arrays are copied in the
        mapping thread and compressed in the decision thread, so frames go on meanwhile. The loops in between
        count at sizes interpolated between the measurements around them (`interpolated_bytes`); a map grows fast
        first and slower later, so the straight line between two measurements lies under the map's growth and
        the baseline is, if anything, understated.
        """
        loop = asyncio.get_running_loop()
        period = self.config.explore.loop_s
        previous, loops = 0, 0
        while not stop.is_set():
            await wait_event(stop, period)
            loops += 1
            if loops < baseline_interval(self.baseline_loops) and not stop.is_set():
                continue
            raw = await loop.run_in_executor(self._worker, self.mapper.fused.wire_raw)
            size = await loop.run_in_executor(self._decider, self._measure_wire_size, raw)
            self.baseline_bytes += interpolated_bytes(previous, size, loops)
            self.baseline_loops += loops
            previous, loops = size, 0

    def _measure_wire_size(self, raw: bytes) -> int:
        with self.clock.measure("whole_map_baseline"):  # a figure for the report, compressed off the mapping thread
            return compressed_size(raw)

    async def seal_last(self) -> None:
        """Seal what is open (after the flight), so nothing seen is lost."""
        await asyncio.get_running_loop().run_in_executor(self._worker, self._seal_last)

    def _seal_last(self) -> None:
        last = self.mapper.seal()
        if last is not None:
            self._keep(last)

    async def close(self) -> None:
        """Write this agent's own fused mesh and stop the worker; nothing can be received after this."""
        await asyncio.get_running_loop().run_in_executor(self._worker, self._measure_memory)
        await asyncio.get_running_loop().run_in_executor(self._worker, self._write_mesh)
        self._worker.shutdown(wait=True)
        self._decider.shutdown(wait=True)

    def _measure_memory(self) -> None:
        """Where the memory went, before the final mesh adds its own: the process's peak and the parts of it
        that this task holds and can count."""
        mapper = self.mapper
        self.memory_mb = {
            "rss_at_start": self._rss_at_start / 2**20,
            "rss_peak_in_flight": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "fused_map": mapper.fused.resident_bytes / 2**20,
            "held_back": mapper.unshared.resident_bytes / 2**20,
            "patch_bytes": (mapper.private.data_bytes + mapper.public.data_bytes) / 2**20,
            "open_patch": mapper.sealer.backend.resident_bytes / 2**20,
        }
        self.memory_mb = {name: round(mb, 1) for name, mb in self.memory_mb.items()}

    def _write_mesh(self) -> None:
        if self.out_dir is not None and self.mapper.fused.voxel_count > 0:
            self.mapper.fused.write_mesh(self.out_dir / f"agent-{self.config.agent.id}.ply")

    def summary(self) -> dict[str, Any]:
        return {
            "patches_sealed": self.patches_sealed,
            "frames": self.frames,
            "frames_skipped": self.frames_skipped,
            "mapping_ms_per_frame": round(1000 * self.busy_s / self.frames, 2) if self.frames else 0.0,
            # frames integrated per second in the air: whatever the camera driver, the transport or this thread
            # could not keep up with shows here (frames_skipped counts only what arrived and was not taken)
            "frame_rate_hz": round(self.frames / self.airborne_s, 2) if self.frames and self.airborne_s > 0 else 0.0,
            "sensor_stream": {
                **self.stream_counters,
                "pixels_masked_as_peers": self.pixels_masked,
                "camera_silences": self.camera_silences,
            }
            if self.stream_counters is not None
            else None,
            "patch_store_failures": dict(self.store_failures),
            "patches_not_sealed": dict(self.mapper.sealer.not_sealed),
            "voxels_held_back": self.mapper.unshared.held_back,
            "patches_held_back": self.mapper.sealer.nothing_to_share,
            "known_voxels": int(self.mapper.fused.voxel_count),
            "memory_mb": dict(self.memory_mb),
            "patches_received": self.patches_received,
            "fused_digest": self.mapper.fused.digest(),
            "whole_map_baseline": {
                "loop_s": self.config.explore.loop_s,
                "loops": self.baseline_loops,
                "bytes": self.baseline_bytes,
            },
        }


def _yield_to_frames() -> None:
    """Run the calling thread DECISION_NICENESS steps nicer than the process: when the cores are short, the
    kernel gives frames (the mapping thread) the time before decisions. Lowering one's own priority needs no
    privilege; where the kernel refuses anyway, the thread keeps the process's."""
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, min(os.getpriority(os.PRIO_PROCESS, tid) + DECISION_NICENESS, 19))
    except OSError:
        pass


def errno_name(exc: OSError) -> str:
    """The name of the error's errno (ENOSPC, EIO, EROFS, ...); "unknown" for an OSError without one."""
    return errno.errorcode.get(exc.errno, "unknown") if exc.errno is not None else "unknown"


def baseline_interval(loops_counted: int) -> int:
    """Loops until the next whole-map measurement, when `loops_counted` are accounted for: as many again (1, 1,
    2, 4, 8, 16 ...), at most BASELINE_SAMPLE_LOOPS."""
    return min(BASELINE_SAMPLE_LOOPS, max(1, loops_counted))


def interpolated_bytes(previous: int, size: int, loops: int) -> int:
    """The summed sizes of `loops` loops whose last measured `size` and whose loop before them measured
    `previous`, each loop in between taken on the straight line from one to the other."""
    return round(sum(previous + (size - previous) * i / loops for i in range(1, loops + 1))) if loops > 0 else 0


def _mark_occupied(states: np.ndarray, origin: np.ndarray, resolution: float, point: Vec3, radius: float) -> None:
    """Mark the cells within `radius` (plus the cell holding it) of `point` occupied."""
    lo = np.floor((np.asarray(point) - radius - origin) / resolution).astype(int)
    hi = np.floor((np.asarray(point) + radius - origin) / resolution).astype(int) + 1
    lo, hi = np.clip(lo, 0, states.shape), np.clip(hi, 0, states.shape)
    states[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]] = OCCUPIED
