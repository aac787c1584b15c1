"""The simulated depth camera: ray casts of the world mesh from the drone's pose.

Conventions (shared with every consumer of a depth image):

- Camera frame as Open3D/OpenCV: x right, y down, z forward. `pose()` returns T_world_cam (camera-to-world).
- Pinhole K with square pixels: fx = fy = (W/2) / tan(hfov/2), cx = W/2, cy = H/2. Pixel (u, v) (column, row)
  covers [u, u+1) x [v, v+1) in image coordinates and its ray goes through its centre (u + 0.5, v + 0.5). That is
  what `RaycastingScene.create_rays_pinhole` casts and what `VoxelBlockGrid.integrate` reads (it projects a voxel
  and truncates to a pixel index); so a point at camera (x, y, z) lands in pixel (floor(fx x/z + cx),
  floor(fy y/z + cy)). Beware: `PointCloud.create_from_depth_image` back-projects pixel u at u, not u + 0.5.
- Depth is z-depth (along the optical axis), float32 metres, 0 = invalid (no return, or outside
  [min_range_m, max_range_m] after noise).
- Noise "stereo" (Hardouin 2022, §1.4): per-pixel z += N(0, (coeff z^2)^2) from a seeded generator, applied to
  every return, then range-gated. The thesis' 3x3 Gaussian smoothing of the depth map is not modelled.

`cast_rays` uses every core (TBB) whatever its thread argument; a 160x120 frame costs ~3.5 ms of CPU.
"""

from __future__ import annotations

import math

import numpy as np

from swarm.config import CameraSettings, Vec3
from swarm.patches.backend import tensor
from swarm.sensing.frames import DepthFrame
from swarm.sim.worlds import World


def intrinsics(settings: CameraSettings) -> np.ndarray:
    """The 3x3 pinhole matrix K of a camera (float64; cx = W/2, cy = H/2, see the module docstring)."""
    w, h = settings.width, settings.height
    f = (w / 2.0) / math.tan(math.radians(settings.hfov_deg) / 2.0)
    return np.array([[f, 0.0, w / 2.0], [0.0, f, h / 2.0], [0.0, 0.0, 1.0]])


def camera_pose(position: Vec3, yaw_enu_deg: float, pitch_deg: float) -> np.ndarray:
    """4x4 camera-to-world transform: camera at `position`, optical axis along the yaw, pitched down by pitch_deg."""
    yaw, pitch = math.radians(yaw_enu_deg), math.radians(pitch_deg)
    forward = np.array([math.cos(yaw) * math.cos(pitch), math.sin(yaw) * math.cos(pitch), -math.sin(pitch)])
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])  # horizontal: the camera does not roll
    down = np.cross(forward, right)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = right, down, forward
    T[:3, 3] = position
    return T


class DepthCamera:
    def __init__(self, world: World, settings: CameraSettings, seed: int = 0) -> None:
        self.world = world
        self.settings = settings
        self.intrinsics = intrinsics(settings)
        self._K = tensor(self.intrinsics)
        self._scene = world.scene  # build the BVH now, not on the first frame
        self._rng = np.random.default_rng(seed)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of a depth image."""
        return self.settings.height, self.settings.width

    def pose(self, position: Vec3, yaw_enu_deg: float) -> np.ndarray:
        """T_world_cam of the camera on a drone at `position` with ENU yaw `yaw_enu_deg` (pitch from settings)."""
        return camera_pose(position, yaw_enu_deg, self.settings.pitch_deg)

    def frame(self, index: int, t: float, position: Vec3, yaw_enu_deg: float) -> DepthFrame:
        """A frame taken from a drone at `position` with ENU yaw `yaw_enu_deg` (the map node's and tests' camera:
        the agents' comes through `swarm cameras`)."""
        T = self.pose(position, yaw_enu_deg)
        return DepthFrame(index, t, self.render(T), self.intrinsics.copy(), T)

    def render(self, T_world_cam: np.ndarray) -> np.ndarray:
        """(H, W) float32 z-depth in metres seen from T_world_cam; 0 where invalid."""
        s = self.settings
        T_cam_world = np.linalg.inv(np.asarray(T_world_cam, dtype=np.float64))
        rays = self._scene.create_rays_pinhole(self._K, tensor(T_cam_world), s.width, s.height)
        # Ray directions have camera-z == 1, so the hit parameter is the z-depth.
        z = self._scene.cast_rays(rays)["t_hit"].numpy()
        z[~np.isfinite(z)] = 0.0
        if s.noise == "stereo":
            z += np.float32(s.stereo_sigma_coeff) * z * z * self._rng.standard_normal(z.shape, dtype=np.float32)
        z[(z < s.min_range_m) | (z > s.max_range_m)] = 0.0
        return z
