"""`swarm export RUN_DIR --mcap BAG`: a finished run as a ROS 2 bag (MCAP storage) for Foxglove, `ros2 bag`, RViz.

Read from the run's own files: the recording (`run.rrd`, through Rerun's reader) for each drone's poses and the
targets its leader gave it, `map.ply` for the final map, `report.json` for the mission clock's zero (message
stamps are Unix time: that zero plus mission time). Topics, all in frame "map" (the world frame, z up, metres):

=====================  ==========================  ======================================================
/drone<K>/odom         nav_msgs/msg/Odometry       each recorded pose (position and yaw), child base_link<K>
/drone<K>/target       geometry_msgs/msg/PointStamped  each target viewpoint assigned to drone K
/drone<K>/path         nav_msgs/msg/Path           the flown path, once, at the drone's last pose
/map                   sensor_msgs/msg/PointCloud2 the final map's surface vertices (x, y, z float32), once
=====================  ==========================  ======================================================

The bag is a directory (as `ros2 bag record` writes it: metadata.yaml and BAG.mcap) and must not exist yet.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer

from swarm.errors import SwarmError
from swarm.files import FileFormatError
from swarm.mission.recording import RECORDING_NAME, entity_rows, entity_spans
from swarm.mission.report import read_report
from swarm.sensing.messages import Pose, header, odometry_message, serialize, typestore

FRAME = "map"
ODOMETRY = "nav_msgs/msg/Odometry"
POINT_STAMPED = "geometry_msgs/msg/PointStamped"
PATH = "nav_msgs/msg/Path"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"
_DRONE_POSE = re.compile(r"^/drones/([0-9]+)/pose$")


def stamp_ns(started_at: float, t: float) -> int:
    """A message's bag time: the mission clock's zero (Unix seconds) plus mission time t, in ns."""
    return round((started_at + t) * 1e9)


def point_cloud(t: float, points: np.ndarray, frame_id: str = FRAME) -> Any:
    """sensor_msgs/PointCloud2 of (N, 3) points: fields x, y, z float32, little endian, unorganised (height 1)."""
    types = typestore().types
    xyz = np.ascontiguousarray(np.asarray(points, dtype="<f4").reshape(-1, 3))
    fields = [
        types["sensor_msgs/msg/PointField"](name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")
    ]
    return types[POINT_CLOUD2](
        header=header(t, frame_id),
        height=1,
        width=len(xyz),
        fields=fields,
        is_bigendian=False,
        point_step=12,
        row_step=12 * len(xyz),
        data=np.frombuffer(xyz.tobytes(), dtype=np.uint8),
        is_dense=True,
    )


def point_stamped(t: float, point: Sequence[float], frame_id: str = FRAME) -> Any:
    types = typestore().types
    x, y, z = (float(c) for c in point)
    return types[POINT_STAMPED](header=header(t, frame_id), point=types["geometry_msgs/msg/Point"](x=x, y=y, z=z))


def path_message(t: float, poses: Sequence[Pose], frame_id: str = FRAME) -> Any:
    types = typestore().types
    stamped = []
    for pose in poses:
        (x, y, z), (qx, qy, qz, qw) = pose.position, pose.orientation
        stamped.append(
            types["geometry_msgs/msg/PoseStamped"](
                header=header(pose.t, frame_id),
                pose=types["geometry_msgs/msg/Pose"](
                    position=types["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z)),
                    orientation=types["geometry_msgs/msg/Quaternion"](
                        x=float(qx), y=float(qy), z=float(qz), w=float(qw)
                    ),
                ),
            )
        )
    return types[PATH](header=header(t, frame_id), poses=stamped)


def drone_poses(recording: Path, drone: int, started_at: float) -> list[Pose]:
    """Drone K's recorded poses, stamped in Unix time."""
    translations = entity_rows([recording], f"/drones/{drone}/pose", "Transform3D:translation")
    quaternions = dict(entity_rows([recording], f"/drones/{drone}/pose", "Transform3D:quaternion"))
    poses = []
    for t, [position] in translations:
        q = quaternions.get(t, [[0.0, 0.0, 0.0, 1.0]])[0]
        poses.append(Pose(t=started_at + t, position=np.asarray(position), orientation=np.asarray(q)))
    return poses


def export_mcap(run_dir: Path, bag: Path) -> dict[str, int]:
    """Write the run as a ROS 2 MCAP bag at `bag`; returns the message count per topic. SwarmError (one line)
    when the run directory lacks what the bag needs or the bag exists."""
    recording = run_dir / RECORDING_NAME
    for needed in (run_dir / "report.json", recording):
        if not needed.is_file():
            raise SwarmError(f"{run_dir}: no {needed.name} (not a finished swarm run, or recorded with --no-rrd)")
    if bag.exists():
        raise SwarmError(f"{bag} already exists")
    try:
        report = read_report(run_dir / "report.json")
    except FileFormatError as exc:
        raise SwarmError(str(exc)) from None
    started = report.started_at
    drones = sorted(int(m.group(1)) for path in entity_spans([recording]) if (m := _DRONE_POSE.match(path)))
    counts: dict[str, int] = {}
    writer = Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    try:

        def write(topic: str, msgtype: str, t_ns: int, message: Any) -> None:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=typestore())
            writer.write(connections[topic], t_ns, serialize(message))
            counts[topic] = counts.get(topic, 0) + 1

        connections: dict[str, Any] = {}
        for k in drones:
            poses = drone_poses(recording, k, started)
            for pose in poses:
                write(f"/drone{k}/odom", ODOMETRY, round(pose.t * 1e9), odometry_message(pose, FRAME, f"base_link{k}"))
            for t, [viewpoint] in entity_rows([recording], f"/drones/{k}/target", "Points3D:positions"):
                write(f"/drone{k}/target", POINT_STAMPED, stamp_ns(started, t), point_stamped(started + t, viewpoint))
            if poses:
                last = poses[-1].t
                write(f"/drone{k}/path", PATH, round(last * 1e9), path_message(last, poses))
        map_path = run_dir / "map.ply"
        if map_path.is_file():
            vertices = _ply_vertices(map_path)
            end = started + report.duration_s
            write("/map", POINT_CLOUD2, round(end * 1e9), point_cloud(end, vertices))
    finally:
        writer.close()
    return counts


def _ply_vertices(path: Path) -> np.ndarray:
    import open3d as o3d

    return np.asarray(o3d.io.read_triangle_mesh(path).vertices, dtype=np.float32).reshape(-1, 3)
