"""`swarm map BAG... --out DIR`: map recorded sensor streams offline, as the agents would have live.

Each bag is one drone: its depth, camera info and pose messages go, in bag time order, through the same
`FrameAssembler` as a live stream, and its frames into a `Mapper` of its own (producer = the bag's position on
the command line), sealed into patches as in flight. The patches of every bag are then fused into one map, as
the swarm's maps converge. The mission volume is `mission.volume` when configured, else the bounding box of every
pose, widened by the camera's range. Out: DIR/patches/*.patch, DIR/map.ply and DIR/report.json (frames and every
dropped message by reason, per bag).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
from rich.progress import Progress

from swarm.config import SwarmConfig
from swarm.errors import SwarmError
from swarm.files import write_atomic
from swarm.patches.fused import FusedMap
from swarm.patches.lattice import Lattice
from swarm.patches.mapper import Mapper
from swarm.sensing.bags import bag_streams
from swarm.sensing.frames import camera_mount
from swarm.sensing.messages import SensorInputError, deserialize, pose_of
from swarm.sensing.poses import PoseBuffer
from swarm.sensing.stream import FrameAssembler


def map_bags(config: SwarmConfig, bags: list[Path], out: Path, topics: dict[str, str | None]) -> dict[str, Any]:
    """Map every bag, fuse, write DIR; the report. SwarmError (one line) for a bag that cannot be used."""
    if out.exists() and any(out.iterdir()):
        raise SwarmError(f"output directory {out} is not empty")
    started = time.monotonic()
    try:
        bounds = _volume(config, bags, topics)
        lattice = Lattice.from_settings(config.mapping)
        fused = FusedMap(lattice, bounds, config.mapping.known_weight)
        (out / "patches").mkdir(parents=True, exist_ok=True)
        per_bag = [_map_one(config, k, bag, bounds, topics, fused, out) for k, bag in enumerate(bags, start=1)]
    except SensorInputError as exc:
        raise SwarmError(str(exc)) from None
    vertices, triangles = fused.write_mesh(out / "map.ply")
    report = {
        "bags": per_bag,
        "volume": {"min": bounds[0].tolist(), "max": bounds[1].tolist()},
        "known_voxels": int(fused.voxel_count),
        "fused_digest": fused.digest(),
        "mesh": {"vertices": vertices, "triangles": triangles},
        "duration_s": round(time.monotonic() - started, 2),
    }
    (out / "report.json").write_text(json.dumps(report, indent=2))
    return report


def _volume(config: SwarmConfig, bags: list[Path], topics: dict[str, str | None]) -> tuple[np.ndarray, np.ndarray]:
    volume = config.mission.volume
    if volume is not None:
        return np.array(volume.min, dtype=float), np.array(volume.max, dtype=float)
    positions = []
    for bag in bags:
        for kind, msgtype, raw, _ in bag_streams([bag], topics.get("depth"), topics.get("info"), topics.get("pose")):
            if kind == "pose":
                try:
                    positions.append(pose_of(deserialize(raw, msgtype)).position)
                except SensorInputError:
                    continue
    if not positions:
        raise SensorInputError(f"no usable pose in {', '.join(map(str, bags))}: give mission.volume")
    reach = config.camera.max_range_m
    return np.min(positions, axis=0) - reach, np.max(positions, axis=0) + reach


def _map_one(
    config: SwarmConfig,
    producer: int,
    bag: Path,
    bounds: tuple[np.ndarray, np.ndarray],
    topics: dict[str, str | None],
    fused: FusedMap,
    out: Path,
) -> dict[str, Any]:
    stream = config.camera.stream
    frames = FrameAssembler(
        camera_mount(config.camera),
        PoseBuffer(max_gap_s=stream.max_gap_s, max_hold_s=stream.max_hold_s),
        max_wait_s=stream.max_pose_wait_s,
    )
    mapper = Mapper(config.mapping, producer, 1, bounds, known_weight=config.mapping.known_weight)
    messages, sealed = 0, []
    with Progress(transient=True) as progress:
        task = progress.add_task(f"mapping {bag.name}", total=None)
        for kind, msgtype, raw, _ in bag_streams([bag], topics.get("depth"), topics.get("info"), topics.get("pose")):
            messages += 1
            if kind == "depth":
                frames.on_image(raw)
            elif kind == "info":
                frames.on_camera_info(raw)
            else:
                frames.on_pose(raw, msgtype)
            for frame in frames.take():
                patch = mapper.integrate(frame.depth, frame.K, frame.T_world_cam, frame.t, config.camera.max_range_m)
                if patch is not None:
                    sealed.append(patch)
            progress.update(task, advance=1)
    last = mapper.seal()
    if last is not None:
        sealed.append(last)
    for patch in sealed:
        data = mapper.data(patch.id)
        assert data is not None
        write_atomic(out / "patches" / f"{patch.id}.patch", data)
        fused.add(patch)
    return {
        "bag": str(bag),
        "producer": producer,
        "messages": messages,
        "frames": frames.frames,
        "dropped": dict(frames.dropped),
        "patches": len(sealed),
    }
