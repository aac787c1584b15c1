"""Sensor streams to and from ROS 2 bags (rosbags): what an agent heard, recorded as it came; and bags, recorded
here or with `ros2 bag record` (ROS 1 `.bag`, ROS 2 sqlite3 and MCAP, through `rosbags.highlevel.AnyReader`),
played back as a camera.

`BagRecorder` writes the raw CDR of every message the agent's sensor session receives, with its receive time, to
a ROS 2 MCAP bag: `ros2 bag`, Foxglove and Rerun open it. `bag_streams` reads a bag's depth, camera info and pose
messages in time order; topics are picked by type when there is one of each, else named by the caller, and a bag
without them is one clear line (`SensorInputError`).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer

from swarm.sensing.messages import (
    CAMERA_INFO,
    IMAGE,
    ODOMETRY,
    POSE_STAMPED,
    SensorInputError,
    convert_message,
    typestore,
)


class BagRecorder:
    """A ROS 2 MCAP bag at `path` (a directory, as ros2 bag writes), safe to write from several threads."""

    def __init__(self, path: Path) -> None:
        if path.exists():
            raise SensorInputError(f"bag {path} already exists")
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._writer: Writer | None = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        self._connections: dict[str, Any] = {}
        self._lock = threading.Lock()
        self.messages = 0

    def write(self, topic: str, msgtype: str, t_ns: int, raw: bytes) -> None:
        with self._lock:
            if self._writer is None:
                return
            connection = self._connections.get(topic)
            if connection is None:
                connection = self._connections[topic] = self._writer.add_connection(
                    topic, msgtype, typestore=typestore()
                )
            self._writer.write(connection, t_ns, raw)
            self.messages += 1

    def close(self) -> None:
        with self._lock:
            if self._writer is not None:
                self._writer.close()
                self._writer = None


@dataclass(frozen=True)
class BagTopics:
    depth: str
    info: str
    pose: str
    pose_type: str


def bag_topics(reader: Any, depth: str | None = None, info: str | None = None, pose: str | None = None) -> BagTopics:
    """The depth, camera info and pose topics of an open bag: the named ones, else the only one of each type."""
    by_topic = {c.topic: c.msgtype for c in reader.connections}
    name = ", ".join(str(p) for p in reader.paths)

    def pick(wanted: str | None, types: tuple[str, ...], what: str, flag: str) -> str:
        if wanted is not None:
            if wanted not in by_topic:
                raise SensorInputError(f"bag {name} has no topic {wanted} (it has {', '.join(sorted(by_topic))})")
            if by_topic[wanted] not in types:
                raise SensorInputError(f"topic {wanted} is {by_topic[wanted]}, not {' or '.join(types)}")
            return wanted
        found = sorted(t for t, kind in by_topic.items() if kind in types)
        if not found:
            raise SensorInputError(f"bag {name} has no {what} topic ({' or '.join(types)})")
        if len(found) > 1:
            raise SensorInputError(f"bag {name} has several {what} topics ({', '.join(found)}): name one with {flag}")
        return found[0]

    depth_topic = pick(depth, (IMAGE,), "depth image", "--depth-topic")
    info_topic = pick(info, (CAMERA_INFO,), "camera info", "--info-topic")
    pose_topic = pick(pose, (ODOMETRY, POSE_STAMPED), "pose", "--pose-topic")
    return BagTopics(depth_topic, info_topic, pose_topic, by_topic[pose_topic])


def bag_streams(
    paths: Sequence[Path], depth: str | None = None, info: str | None = None, pose: str | None = None
) -> Iterator[tuple[str, str, bytes, int]]:
    """(kind, msgtype, raw CDR, bag time ns) of one recording's depth ('depth'), camera info ('info') and pose
    ('pose') messages, in bag time order. A ROS 1 bag's messages come as ROS 1 serialisation: they are converted
    to CDR first."""
    missing = [p for p in paths if not Path(p).exists()]
    if missing:
        raise SensorInputError(f"bag {missing[0]} does not exist")
    try:
        reader = AnyReader([Path(p) for p in paths], default_typestore=typestore())
        reader.open()
    except Exception as exc:  # rosbags raises its own errors per format
        raise SensorInputError(f"cannot read bag {', '.join(map(str, paths))}: {exc}") from None
    try:
        store = typestore()
        topics = bag_topics(reader, depth, info, pose)
        kinds = {topics.depth: "depth", topics.info: "info", topics.pose: "pose"}
        connections = [c for c in reader.connections if c.topic in kinds]
        for connection, t_ns, raw in reader.messages(connections=connections):
            if connection.msgtype is None:
                continue
            if reader.is2:
                data = bytes(raw)
            else:  # ROS 1: deserialise, rebuild as ROS 2 (CameraInfo's K is k there), then CDR: one format downstream
                ros2 = convert_message(reader.deserialize(raw, connection.msgtype), connection.msgtype, store)
                data = bytes(store.serialize_cdr(ros2, connection.msgtype))
            yield kinds[connection.topic], connection.msgtype, data, int(t_ns)
    finally:
        reader.close()
