"""ROS 2 sensor messages to arrays and back, through the `rosbags` typestore (CDR with its encapsulation header).

Conventions out of this module: depth is float32 z-depth in metres with 0 for invalid; intrinsics are a 3x3
pinhole matrix in the ROS convention (pixel (u, v) centred at (u, v)); a pose is a position and an (x, y, z, w)
unit quaternion of the body in the world frame; stamps are seconds. Every malformed message raises
`SensorInputError` with one line that says what is wrong, for the caller to count and drop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore

from swarm.errors import SwarmError

IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
MAX_IMAGE_SIDE = 4096  # a larger depth image is a corrupt header, not a camera
_DEPTH_DTYPES = {"16UC1": "u2", "mono16": "u2", "32FC1": "f4"}
_UNIT_QUATERNION_TOLERANCE = 1e-3  # |q| within this of 1 is renormalised; further off, the pose is rejected


class SensorInputError(SwarmError, ValueError):
    """A sensor message that cannot be used (counted and dropped by the stream that received it)."""


class UnknownEncodingError(SensorInputError):
    """An image whose encoding is no depth encoding this reads (rgb8 from a colour topic, say): a well-formed
    message on the wrong topic, counted apart from broken ones."""


@lru_cache(maxsize=1)
def typestore() -> Any:
    """The ROS 2 message definitions (Humble: these messages are the same in every distribution since)."""
    return get_typestore(Stores.ROS2_HUMBLE)


def convert_message(message: Any, msgtype: str, store: Any) -> Any:
    """`message` rebuilt as `store`'s `msgtype`, field by field: a ROS 1 message as ROS 2 or back. Fields are
    matched by name, then case-insensitively (ROS 1 CameraInfo's D, K, R, P are ROS 2's d, k, r, p); a scalar
    field the message lacks (ROS 1 Header's seq, going the other way) gets its zero. Raises SensorInputError when
    a nested field is missing (the two definitions differ in more than spelling)."""
    from rosbags.interfaces import Nodetype

    values = {}
    for name, (kind, spec) in store.fielddefs[msgtype][1]:
        names = {n.lower(): n for n in vars(message)} if hasattr(message, "__dict__") else {}
        source = name if hasattr(message, name) else names.get(name.lower())
        if source is None:
            if kind != Nodetype.BASE:
                raise SensorInputError(f"{msgtype}: no field {name} to convert")
            values[name] = "" if spec[0] == "string" else (False if spec[0] == "bool" else 0)
            continue
        value = getattr(message, source)
        if kind == Nodetype.NAME:
            value = convert_message(value, spec, store)
        elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE) and spec[0][0] == Nodetype.NAME:
            value = [convert_message(v, spec[0][1], store) for v in value]
        values[name] = value
    return store.types[msgtype](**values)


@dataclass(frozen=True)
class Pose:
    t: float  # seconds
    position: np.ndarray  # (3,) metres, world frame
    orientation: np.ndarray  # (4,) unit quaternion x, y, z, w: body to world


@dataclass(frozen=True)
class Intrinsics:
    width: int
    height: int
    K: np.ndarray  # 3x3, ROS convention (pixel centres at integer coordinates)


def stamp_s(header: Any) -> float:
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def deserialize(raw: bytes | bytearray | memoryview, msgtype: str) -> Any:
    """A message from its CDR bytes; SensorInputError when they do not decode as `msgtype`."""
    try:
        return typestore().deserialize_cdr(bytes(raw), msgtype)
    except Exception as exc:  # rosbags raises several kinds (struct.error, IndexError, ...) on truncated data
        raise SensorInputError(f"not a {msgtype}: {type(exc).__name__}: {exc}") from None


def serialize(message: Any) -> bytes:
    return bytes(typestore().serialize_cdr(message, message.__msgtype__))


def depth_of(image: Any) -> tuple[float, np.ndarray]:
    """(stamp, (H, W) float32 metres, 0 = invalid) of a depth `sensor_msgs/msg/Image`: 16UC1 (or mono16) in
    millimetres with 0 invalid, or 32FC1 in metres with NaN, inf and values <= 0 invalid; `step` (row stride,
    padding allowed) and `is_bigendian` honoured."""
    kind = _DEPTH_DTYPES.get(image.encoding)
    if kind is None:
        raise UnknownEncodingError(f"depth encoding '{image.encoding}' is not one of {', '.join(_DEPTH_DTYPES)}")
    h, w, step = int(image.height), int(image.width), int(image.step)
    if not (0 < h <= MAX_IMAGE_SIDE and 0 < w <= MAX_IMAGE_SIDE):
        raise SensorInputError(f"depth image of {w}x{h} pixels")
    dtype = np.dtype(kind).newbyteorder(">" if image.is_bigendian else "<")
    if step < w * dtype.itemsize:
        raise SensorInputError(f"row step {step} B is short of {w} pixels of {dtype.itemsize} B")
    data = np.asarray(image.data, dtype=np.uint8)
    if data.size < step * (h - 1) + w * dtype.itemsize:
        raise SensorInputError(f"{data.size} B of data for {h} rows of {step} B")
    rows = np.lib.stride_tricks.as_strided(data, shape=(h, w * dtype.itemsize), strides=(step, 1))
    pixels = np.ascontiguousarray(rows).view(dtype).reshape(h, w)
    if kind == "u2":
        depth = pixels.astype(np.float32) * np.float32(0.001)
    else:
        depth = pixels.astype(np.float32)
        depth[~np.isfinite(depth) | (depth < 0)] = 0.0
    return stamp_s(image.header), depth


def intrinsics_of(info: Any) -> Intrinsics:
    """The pinhole intrinsics of a `sensor_msgs/msg/CameraInfo` (depth images come rectified: `d` is ignored)."""
    k = np.asarray(info.k, dtype=np.float64).reshape(-1)
    w, h = int(info.width), int(info.height)
    if k.size != 9 or not np.all(np.isfinite(k)):
        raise SensorInputError("camera info K is not 9 finite numbers")
    K = k.reshape(3, 3)
    if not (K[0, 0] > 0 and K[1, 1] > 0) or not (0 < w <= MAX_IMAGE_SIDE and 0 < h <= MAX_IMAGE_SIDE):
        raise SensorInputError(f"camera info with fx {K[0, 0]:g}, fy {K[1, 1]:g} for {w}x{h} pixels")
    return Intrinsics(w, h, K)


def pose_of(message: Any) -> Pose:
    """The body pose of a `nav_msgs/msg/Odometry` or `geometry_msgs/msg/PoseStamped`."""
    kind = getattr(message, "__msgtype__", "")
    if kind == ODOMETRY:
        pose = message.pose.pose
    elif kind == POSE_STAMPED:
        pose = message.pose
    else:
        raise SensorInputError(f"a pose is {ODOMETRY} or {POSE_STAMPED}, not {kind or type(message).__name__}")
    p, q = pose.position, pose.orientation
    position = np.array([p.x, p.y, p.z], dtype=np.float64)
    quaternion = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
    norm = float(np.linalg.norm(quaternion))
    if not (np.all(np.isfinite(position)) and math.isfinite(norm)) or abs(norm - 1.0) > _UNIT_QUATERNION_TOLERANCE:
        raise SensorInputError(f"pose with position {position.tolist()} and quaternion of norm {norm:.4g}")
    t = stamp_s(message.header)
    if not math.isfinite(t):
        raise SensorInputError("pose without a finite stamp")
    return Pose(t, position, quaternion / norm)


# -- writing (the simulator publishes, tests and recordings make bags) --------------------------------------------


def header(t: float, frame_id: str) -> Any:
    types = typestore().types
    sec = math.floor(t)
    nanosec = min(round((t - sec) * 1e9), 999_999_999)
    return types["std_msgs/msg/Header"](
        stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id
    )


def depth_millimetres(depth_m: np.ndarray) -> np.ndarray:
    """Depth in metres (0 or NaN = invalid) as 16UC1's little-endian millimetres (0 = invalid, 65.535 m at most)."""
    return np.clip(np.rint(np.nan_to_num(np.asarray(depth_m, dtype=np.float32)) * 1000.0), 0, 65535).astype("<u2")


def image_message(t: float, depth_m: np.ndarray, frame_id: str = "camera_optical", encoding: str = "32FC1") -> Any:
    """A depth image of `depth_m` (metres, 0 = invalid): 32FC1 metres (0 -> NaN) or 16UC1 millimetres."""
    depth = np.asarray(depth_m, dtype=np.float32)
    if encoding == "32FC1":
        pixels = np.where(depth > 0, depth, np.float32(np.nan)).astype("<f4")
    elif encoding == "16UC1":
        pixels = depth_millimetres(depth)
    else:
        raise ValueError(f"cannot write depth as '{encoding}'")
    h, w = depth.shape
    return typestore().types[IMAGE](
        header=header(t, frame_id),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=w * pixels.dtype.itemsize,
        data=np.frombuffer(pixels.tobytes(), dtype=np.uint8),
    )


def camera_info_message(t: float, intrinsics: Intrinsics, frame_id: str = "camera_optical") -> Any:
    types = typestore().types
    K = np.asarray(intrinsics.K, dtype=np.float64)
    P = np.zeros((3, 4))
    P[:, :3] = K
    return types[CAMERA_INFO](
        header=header(t, frame_id),
        height=intrinsics.height,
        width=intrinsics.width,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=K.reshape(9),
        r=np.eye(3).reshape(9),
        p=P.reshape(12),
        binning_x=0,
        binning_y=0,
        roi=types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )


def odometry_message(pose: Pose, frame_id: str = "map", child_frame_id: str = "base_link") -> Any:
    types = typestore().types
    (x, y, z), (qx, qy, qz, qw) = pose.position, pose.orientation
    geometry = types["geometry_msgs/msg/Pose"](
        position=types["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z)),
        orientation=types["geometry_msgs/msg/Quaternion"](x=float(qx), y=float(qy), z=float(qz), w=float(qw)),
    )
    zero = types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    return types[ODOMETRY](
        header=header(pose.t, frame_id),
        child_frame_id=child_frame_id,
        pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=geometry, covariance=np.zeros(36)),
        twist=types["geometry_msgs/msg/TwistWithCovariance"](
            twist=types["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)
        ),
    )
