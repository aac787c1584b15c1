"""Where the camera is: the vehicle's pose, times the camera's mounting transform, times the optical frame.

Frames. The world is ENU (x east, y north, z up), the vehicle's body FLU (x forward, y left, z up; REP-103). The
mount gives the camera link in the body frame: a translation in metres and a rotation as roll, pitch, yaw in
degrees (intrinsic z-y'-x'', as URDF's rpy; a positive pitch looks down). The camera link is FLU too (x along the
optical axis); ROS images are in the optical frame (x right, y down, z forward), which `OPTICAL_IN_LINK` turns it
into. `T_world_cam` is then camera-to-world in the optical frame, what the mapper integrates with.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from swarm.config import CameraSettings, Vec3
from swarm.sensing.messages import Intrinsics, Pose


@dataclass(frozen=True)
class DepthFrame:
    """One depth image with its camera pose, as the mapper integrates it."""

    index: int  # frame counter of the agent
    t: float  # capture time, seconds (the image's stamp)
    depth: np.ndarray  # (H, W) float32 z-depth, metres; 0 = invalid
    K: np.ndarray  # 3x3 pinhole intrinsics, pixel (u, v) centred at (u + 0.5, v + 0.5)
    T_world_cam: np.ndarray  # 4x4 camera-to-world; optical frame: x right, y down, z forward

    def world_points(self) -> np.ndarray:
        """(N, 3) world points of the valid pixels (back-projected through the pixel centres)."""
        v, u = np.nonzero(self.depth > 0)
        z = self.depth[v, u].astype(np.float64)
        (fx, _, cx), (_, fy, cy) = self.K[0], self.K[1]
        cam = np.stack([(u + 0.5 - cx) / fx * z, (v + 0.5 - cy) / fy * z, z], axis=1)
        return cam @ self.T_world_cam[:3, :3].T + self.T_world_cam[:3, 3]


# Columns: the optical frame's x (right), y (down) and z (forward) axes in the FLU camera link.
OPTICAL_IN_LINK = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def mount_transform(translation_m: Vec3, rpy_deg: Vec3) -> np.ndarray:
    """4x4 optical-frame-to-body transform of a camera mounted at `translation_m` with `rpy_deg`."""
    roll, pitch, yaw = rpy_deg
    T = np.eye(4)
    # URDF rpy: fixed-axis x, y, z (roll first) = intrinsic z-y'-x''; a positive pitch about y (left) looks down
    T[:3, :3] = Rotation.from_euler("xyz", [roll, pitch, yaw], degrees=True).as_matrix() @ OPTICAL_IN_LINK
    T[:3, 3] = translation_m
    return T


def camera_mount(camera: CameraSettings) -> np.ndarray:
    """The mount of `camera`: camera.mount, with camera.pitch_deg added to its pitch."""
    roll, pitch, yaw = camera.mount.rpy_deg
    return mount_transform(camera.mount.translation_m, (roll, pitch + camera.pitch_deg, yaw))


def body_to_world(pose: Pose) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(pose.orientation).as_matrix()
    T[:3, 3] = pose.position
    return T


def camera_to_world(pose: Pose, mount: np.ndarray) -> np.ndarray:
    """T_world_cam (optical frame) of a camera with mounting transform `mount` on a vehicle at `pose`."""
    return body_to_world(pose) @ mount


def pixel_centre_intrinsics(intrinsics: Intrinsics) -> np.ndarray:
    """K in the mapper's convention, pixel (u, v) centred at (u + 0.5, v + 0.5): ROS centres it at (u, v)."""
    K = np.array(intrinsics.K, dtype=np.float64)
    K[0, 2] += 0.5
    K[1, 2] += 0.5
    return K
