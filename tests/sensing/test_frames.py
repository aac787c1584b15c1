"""The camera on the vehicle: a mount with a pitch matches the simulator's camera, the optical axes are where
ROS puts them, a tilted vehicle tilts its camera, and ROS intrinsics move to the mapper's pixel centres."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from swarm.sensing.frames import camera_to_world, mount_transform, pixel_centre_intrinsics
from swarm.sensing.messages import Intrinsics, Pose
from swarm.sim.camera import camera_pose


@pytest.mark.parametrize(("yaw", "pitch"), [(0.0, 0.0), (37.0, 20.0), (-120.0, -10.0)])
def test_a_level_vehicle_with_a_pitched_mount_sees_what_the_simulated_camera_sees(yaw: float, pitch: float) -> None:
    pose = Pose(0.0, np.array([1.0, 2.0, 1.5]), Rotation.from_euler("z", yaw, degrees=True).as_quat())
    T = camera_to_world(pose, mount_transform((0.0, 0.0, 0.0), (0.0, pitch, 0.0)))
    assert np.allclose(T, camera_pose((1.0, 2.0, 1.5), yaw, pitch), atol=1e-12)


def test_the_optical_frame_is_x_right_y_down_z_forward_and_the_mount_offset_is_in_the_body_frame() -> None:
    pose = Pose(0.0, np.zeros(3), Rotation.from_euler("z", 90, degrees=True).as_quat())  # facing north
    T = camera_to_world(pose, mount_transform((0.1, 0.0, -0.05), (0.0, 0.0, 0.0)))
    assert np.allclose(T[:3, 2], [0, 1, 0]) and np.allclose(T[:3, 0], [1, 0, 0]) and np.allclose(T[:3, 1], [0, 0, -1])
    assert np.allclose(T[:3, 3], [0.0, 0.1, -0.05])  # 10 cm ahead of the body: north


def test_a_vehicle_pitched_forward_points_its_camera_down() -> None:
    nose_down = Pose(0.0, np.zeros(3), Rotation.from_euler("y", 15, degrees=True).as_quat())
    forward = camera_to_world(nose_down, mount_transform((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)))[:3, 2]
    assert forward[2] == pytest.approx(-np.sin(np.radians(15)))


def test_ros_intrinsics_move_half_a_pixel_to_the_mappers_pixel_centres() -> None:
    K = np.array([[80.0, 0.0, 79.5], [0.0, 80.0, 59.5], [0.0, 0.0, 1.0]])
    ours = pixel_centre_intrinsics(Intrinsics(160, 120, K))
    assert ours[0, 2] == 80.0 and ours[1, 2] == 60.0 and K[0, 2] == 79.5  # the input is not changed
