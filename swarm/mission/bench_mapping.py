"""`swarm bench mapping`: the single-core cost of the mapping pipeline, at 0.1 m and 0.2 m voxels.

Each voxel size runs in its own child process pinned to one CPU with OMP_NUM_THREADS=1 (Open3D's ray casting
uses every core through TBB whatever it is told; only the affinity mask stops it). The child flies the camera
(config.camera, 160x120 by default) along the office corridor at 1 m/s, scanning left and right, renders each
depth frame by ray casting the world mesh, integrates it, seals patches (config.mapping triggers), then encodes,
decodes and fuses every patch into a receiver's map, exports the planning occupancy grid and the mesh. At 0.1 m
it also measures the streamed camera's path per frame (camera.source = "zenoh": serialise, Zenoh transport on
loopback, decode and pose lookup). Figures are medians over frames or patches unless named p95/max.
"""

from __future__ import annotations

import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from swarm.config import SwarmConfig

VOXEL_SIZES = (0.1, 0.2)
FRAMES = 150
SPEED_M_S = 1.0
TARGETS = {  # (figure, voxel size, limit, unit)
    "integrate_ms": (0.1, 8.0, "ms per frame"),
    "patch_kb_max": (0.1, 300.0, "kB per 15-frame patch"),
    "decode_fuse_ms": (0.1, 10.0, "ms per patch"),
    "stream_frame_ms": (0.1, 1.0, "ms per streamed frame"),
}


def bench_mapping(config: SwarmConfig, out: Path | None) -> int:
    from rich.console import Console

    console = Console()
    if not console.is_terminal:
        console = Console(width=160)
    results: dict[str, Any] = {}
    for voxel in VOXEL_SIZES:
        console.print(f"bench mapping: {voxel} m voxels in '{config.mission.world}' (one core) ...")
        results[f"{voxel:g}"] = _run_child(config, voxel)
    _print(console, results)
    root = out or Path(tempfile.mkdtemp(prefix="swarm-bench-"))
    root.mkdir(parents=True, exist_ok=True)
    path = root / "bench-mapping.json"
    figures = {"world": config.mission.world, "results": results, "targets": _verdicts(results)}
    path.write_text(json.dumps(figures, indent=2))
    console.print(f"figures: {path}")
    return 0


def _run_child(config: SwarmConfig, voxel: float) -> dict[str, Any]:
    spec = {"config": config.model_dump(mode="json"), "voxel": voxel}
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    proc = subprocess.run(
        [sys.executable, "-m", "swarm.mission.bench_mapping"],
        input=json.dumps(spec),
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"mapping bench child failed: {proc.stderr.strip()[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _verdicts(results: dict[str, Any]) -> dict[str, Any]:
    verdicts = {}
    for name, (voxel, limit, unit) in TARGETS.items():
        value = results.get(f"{voxel:g}", {}).get(name)
        met = value is not None and value <= limit
        verdicts[name] = {"voxel": voxel, "limit": limit, "unit": unit, "value": value, "met": met}
    return verdicts


_ROWS = (  # (key, label, format)
    ("raycast_ms", "ray cast, ms/frame", "{:.2f}"),
    ("integrate_ms", "integrate (blocks + TSDF), ms/frame", "{:.2f}"),
    ("integrate_p95_ms", "integrate p95, ms/frame", "{:.2f}"),
    ("blocks_per_frame", "blocks touched per frame", "{:.0f}"),
    ("integrate_inverse_square_ms", "integrate, inverse-square law, ms/frame", "{:.2f}"),
    ("seal_ms", "seal (extract + quantise + reset), ms/patch", "{:.2f}"),
    ("patches", "patches sealed", "{:.0f}"),
    ("frames_per_patch", "frames per patch", "{:.0f}"),
    ("blocks_per_patch", "blocks per patch", "{:.0f}"),
    ("patch_kb", "patch size, kB", "{:.1f}"),
    ("patch_kb_max", "patch size max, kB", "{:.1f}"),
    ("raw_kb", "patch raw size (before zstd), kB", "{:.1f}"),
    ("encode_ms", "encode, ms/patch", "{:.2f}"),
    ("decode_ms", "decode, ms/patch", "{:.2f}"),
    ("fuse_ms", "fuse, ms/patch", "{:.2f}"),
    ("decode_fuse_ms", "decode + fuse, ms/patch", "{:.2f}"),
    ("fused_blocks", "fused map blocks", "{:.0f}"),
    ("known_fraction", "known fraction of the world box", "{:.3f}"),
    ("occupancy_ms", "occupancy grid export, ms", "{:.1f}"),
    ("occupancy_cells", "occupancy grid cells", "{:.0f}"),
    ("digest_ms", "map digest, ms", "{:.1f}"),
    ("mesh_ms", "mesh (marching cubes), ms", "{:.0f}"),
    ("mesh_triangles", "mesh triangles", "{:.0f}"),
    ("stream_frame_kb", "streamed depth image (32FC1 CDR), kB", "{:.1f}"),
    ("stream_serialize_ms", "camera driver: serialise image + info, ms/frame", "{:.2f}"),
    ("stream_transport_ms", "Zenoh loopback publish to callback, ms/frame", "{:.2f}"),
    ("stream_decode_pose_ms", "agent: decode + pose lookup + assembly, ms/frame", "{:.2f}"),
    ("stream_frame_ms", "agent: transport + decode + pose lookup, ms/frame", "{:.2f}"),
    ("rss_mb", "RSS at the end, MB", "{:.0f}"),
    ("peak_rss_mb", "peak RSS, MB", "{:.0f}"),
)


def _print(console: Any, results: dict[str, Any]) -> None:
    from rich.table import Table

    sizes = list(results)
    table = Table(title="swarm bench mapping (one core, OMP_NUM_THREADS=1; medians unless noted)")
    table.add_column("figure")
    for size in sizes:
        table.add_column(f"{size} m", justify="right")
    table.add_column("target", justify="right")
    verdicts = _verdicts(results)
    for key, label, fmt in _ROWS:
        cells = [fmt.format(results[s][key]) if results[s].get(key) is not None else "-" for s in sizes]
        target = ""
        if key in verdicts:
            v = verdicts[key]
            target = f"<= {v['limit']:g} at {v['voxel']:g} m: {'met' if v['met'] else 'MISSED'}"
        table.add_row(label, *cells, target)
    console.print(table)


# --- the measuring child ---------------------------------------------------------------------------------------


def _flight(world: Any, settings: Any, altitude: float) -> list[np.ndarray]:
    """Camera poses along the corridor of the world (the office's y = 10 m), scanning +-75 degrees."""
    from swarm.sim.camera import camera_pose

    lo, hi = world.bounds
    start = np.array(world.default_start, dtype=np.float64)
    step = SPEED_M_S / settings.rate_hz
    poses = []
    for i in range(FRAMES):
        x = min(start[0] + step * i, hi[0] - 1.0)
        yaw = 75.0 * math.sin(2.0 * math.pi * i / 40.0)
        poses.append(camera_pose((x, start[1], start[2] + altitude), yaw, settings.pitch_deg))
    return poses


def flight_patches(config: SwarmConfig, limit: int) -> list[Any]:
    """Up to `limit` patches sealed by producer 1 along the corridor flight (`_flight`) in the mission's world, with
    the mission's mapping and a noiseless camera: real patches for measuring what is done to them."""
    from swarm.patches.mapper import Mapper
    from swarm.sim.camera import DepthCamera
    from swarm.sim.worlds import load_world

    world = load_world(config.mission.world)
    cam_settings = config.camera.model_copy(update={"noise": "off"})
    camera = DepthCamera(world, cam_settings)
    mapper = Mapper(config.mapping, 1, int(time.time() * 1000), world.bounds)
    patches = []
    for i, T in enumerate(_flight(world, cam_settings, config.agent.altitude_m)):
        patch = mapper.integrate(
            camera.render(T), camera.intrinsics, T, i / cam_settings.rate_hz, cam_settings.max_range_m
        )
        if patch is not None:
            patches.append(patch)
            if len(patches) >= limit:
                break
    return patches


class _TimedBackend:
    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.lattice = inner.lattice
        self.integrate_s: list[float] = []

    def integrate(self, depth: np.ndarray, K: np.ndarray, T: np.ndarray, max_range: float) -> None:
        t0 = time.perf_counter()
        self.inner.integrate(depth, K, T, max_range)
        self.integrate_s.append(time.perf_counter() - t0)

    @property
    def block_count(self) -> int:
        return int(self.inner.block_count)

    @property
    def resident_bytes(self) -> int:
        return int(self.inner.resident_bytes)

    def extract(self) -> Any:
        return self.inner.extract()

    def keys(self) -> np.ndarray:
        return self.inner.keys()

    def reset(self) -> None:
        self.inner.reset()


def _ms(values: list[float]) -> float:
    return float(np.median(values) * 1e3) if values else float("nan")


def _measure(config: SwarmConfig, voxel: float) -> dict[str, Any]:
    import psutil

    from swarm.patches.backend import VoxelBlockGridBackend
    from swarm.patches.carving import frame_blocks
    from swarm.patches.fused import FusedMap
    from swarm.patches.lattice import Lattice
    from swarm.patches.sealer import PatchSealer
    from swarm.patches.wire import decode_patch, encode_patch
    from swarm.sim.camera import DepthCamera
    from swarm.sim.worlds import load_world

    world = load_world(config.mission.world)
    cam_settings = config.camera.model_copy(update={"noise": "off"})
    camera = DepthCamera(world, cam_settings)
    K, max_range = camera.intrinsics, cam_settings.max_range_m
    mapping = config.mapping.model_copy(update={"voxel_size_m": voxel})
    lattice = Lattice.from_settings(mapping)
    bounds = world.bounds

    frames, raycast_s = [], []
    for T in _flight(world, cam_settings, config.agent.altitude_m):
        t0 = time.perf_counter()
        depth = camera.render(T)
        raycast_s.append(time.perf_counter() - t0)
        frames.append((T, depth))

    backend = _TimedBackend(VoxelBlockGridBackend(lattice))
    sealer = PatchSealer(backend, 1, int(time.time() * 1000), mapping.patch_frames, mapping.patch_distance_m)
    patches, seal_s = [], []
    for i, (T, depth) in enumerate(frames):
        t0 = time.perf_counter()
        patch = sealer.add_frame(depth, K, T, i / cam_settings.rate_hz, max_range)
        if patch is not None:
            seal_s.append(time.perf_counter() - t0 - backend.integrate_s[-1])
            patches.append(patch)
    blocks_per_frame = [
        len(frame_blocks(d, K, lattice.to_lattice_frame(T), lattice, max_range)) for T, d in frames[::10]
    ]

    inverse = VoxelBlockGridBackend(Lattice.from_settings(mapping.model_copy(update={"weight_law": "inverse_square"})))
    inverse_s = []
    for i, (T, depth) in enumerate(frames):
        if i % mapping.patch_frames == 0:
            inverse.reset()
        t0 = time.perf_counter()
        inverse.integrate(depth, K, T, max_range)
        inverse_s.append(time.perf_counter() - t0)

    encoded, encode_s, decode_s, fuse_s = [], [], [], []
    receiver = FusedMap(lattice, bounds)
    for patch in patches:
        t0 = time.perf_counter()
        data = encode_patch(patch)
        t1 = time.perf_counter()
        decoded = decode_patch(data, lattice, mapping.max_patch_bytes)
        t2 = time.perf_counter()
        receiver.add(decoded)
        t3 = time.perf_counter()
        encoded.append(data)
        encode_s.append(t1 - t0)
        decode_s.append(t2 - t1)
        fuse_s.append(t3 - t2)
    full = [len(d) for d, p in zip(encoded, patches) if p.span.frames == mapping.patch_frames]
    full = full or [len(d) for d in encoded]
    raw_bytes = [p.block_count * (6 + (1 + lattice.weight_dtype.itemsize) * lattice.voxels_per_block) for p in patches]

    stream = _stream_costs(frames, K, cam_settings) if voxel == VOXEL_SIZES[0] else {}

    occupancy_s = []
    for _ in range(3):
        t0 = time.perf_counter()
        _, grid = receiver.occupancy_grid(mapping.planning_resolution_m)
        occupancy_s.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    receiver.digest()
    digest_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    _, triangles = receiver.mesh()
    mesh_s = time.perf_counter() - t0

    return {
        "voxel": voxel,
        "frames": len(frames),
        "image": [cam_settings.width, cam_settings.height],
        "raycast_ms": _ms(raycast_s),
        "integrate_ms": _ms(backend.integrate_s),
        "integrate_p95_ms": float(np.percentile(backend.integrate_s, 95) * 1e3),
        "blocks_per_frame": float(np.median(blocks_per_frame)),
        "integrate_inverse_square_ms": _ms(inverse_s),
        "seal_ms": _ms(seal_s),
        "patches": len(patches),
        "frames_per_patch": float(np.median([p.span.frames for p in patches])) if patches else 0.0,
        "blocks_per_patch": float(np.median([p.block_count for p in patches])) if patches else 0.0,
        "patch_kb": float(np.median([len(d) for d in encoded]) / 1024) if encoded else 0.0,
        "patch_kb_max": float(max(full) / 1024) if encoded else 0.0,
        "raw_kb": float(np.median(raw_bytes) / 1024) if raw_bytes else 0.0,
        "encode_ms": _ms(encode_s),
        "decode_ms": _ms(decode_s),
        "fuse_ms": _ms(fuse_s),
        "decode_fuse_ms": _ms([d + f for d, f in zip(decode_s, fuse_s)]),
        "fused_blocks": receiver.block_count,
        "known_fraction": receiver.known_fraction,
        "occupancy_ms": _ms(occupancy_s),
        "occupancy_cells": int(grid.size),
        "digest_ms": digest_s * 1e3,
        "mesh_ms": mesh_s * 1e3,
        "mesh_triangles": int(len(triangles)),
        **stream,
        "rss_mb": psutil.Process().memory_info().rss / 2**20,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def _stream_costs(frames: list[tuple[np.ndarray, np.ndarray]], K: np.ndarray, settings: Any) -> dict[str, float]:
    """The live path's cost per frame (camera.source = "zenoh"): the camera driver's serialisation of an image and
    its camera info, their transport between two Zenoh sessions on loopback TCP (publish to callback), and the
    agent's decode, pose lookup and frame assembly. 50 Hz odometry around every frame, as the simulator sends."""
    import threading

    import zenoh

    from swarm.sensing import messages as m
    from swarm.sensing.stream import FrameAssembler
    from swarm.sim.sensors import body_pose

    ros_K = np.array(K, dtype=np.float64)
    ros_K[0, 2] -= 0.5
    ros_K[1, 2] -= 0.5
    info = m.Intrinsics(settings.width, settings.height, ros_K)
    assembler = FrameAssembler(np.eye(4))
    assembler.on_camera_info(m.serialize(m.camera_info_message(0.0, info)))
    serialize_s, decode_s, transport_s, sizes = [], [], [], []
    port = 47000 + os.getpid() % 1000
    configs = []
    for mode, endpoints in (("listen", f'["tcp/127.0.0.1:{port}"]'), ("connect", f'["tcp/127.0.0.1:{port}"]')):
        c = zenoh.Config()
        c.insert_json5("mode", '"peer"')
        c.insert_json5(f"{mode}/endpoints", endpoints)
        c.insert_json5("scouting/multicast/enabled", "false")
        configs.append(c)
    publisher, subscriber = zenoh.open(configs[0]), zenoh.open(configs[1])
    arrived = threading.Event()
    received: list[float] = []

    def on_sample(sample: zenoh.Sample) -> None:
        received.append(time.perf_counter())
        arrived.set()

    sub = subscriber.declare_subscriber("bench/image", on_sample)
    try:
        for _ in range(100):  # the subscription reaches the publisher
            publisher.put("bench/image", b"warm-up")
            if arrived.wait(0.05):
                break
        for i, (T, depth) in enumerate(frames):
            t = 10.0 + i / settings.rate_hz
            for j in range(5):  # odometry every 20 ms, the frame in the middle
                assembler.on_pose(body_pose(t - 0.04 + 0.02 * j, T[:3, 3], 0.0, 0.0, 0.0))
            t0 = time.perf_counter()
            raw = m.serialize(m.image_message(t, depth))
            m.serialize(m.camera_info_message(t, info))
            serialize_s.append(time.perf_counter() - t0)
            sizes.append(len(raw))
            arrived.clear()
            t1 = time.perf_counter()
            publisher.put("bench/image", raw)
            if arrived.wait(1.0):
                transport_s.append(received[-1] - t1)
            t2 = time.perf_counter()
            assembler.on_image(raw)
            assert assembler.take(), assembler.dropped
            decode_s.append(time.perf_counter() - t2)
    finally:
        sub.undeclare()
        publisher.close()
        subscriber.close()
    return {
        "stream_serialize_ms": _ms(serialize_s),
        "stream_transport_ms": _ms(transport_s),
        "stream_decode_pose_ms": _ms(decode_s),
        "stream_frame_ms": _ms(transport_s) + _ms(decode_s),
        "stream_frame_kb": float(np.median(sizes) / 1024),
    }


def _child() -> None:
    cpus = sorted(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {cpus[0]})
    spec = json.loads(sys.stdin.read())
    config = SwarmConfig.model_validate(spec["config"])
    print(json.dumps(_measure(config, float(spec["voxel"]))))


if __name__ == "__main__":
    _child()
