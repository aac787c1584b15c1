import math

import numpy as np
import pytest

from swarm.config import CameraSettings
from swarm.sim.camera import DepthCamera, camera_pose
from swarm.sim.worlds import World, boxes_to_mesh


def wall_world(d: float, post: bool = False) -> World:
    """A wall whose face is the plane x = d (every box exact, unshrunk); optionally a post right of the +x axis."""
    boxes = [((d, -50.0, -50.0), (d + 0.2, 50.0, 50.0))]
    if post:
        boxes.append(((d / 2, -2.0, -50.0), (d / 2 + 0.2, -0.5, 50.0)))  # y < 0: on the right when facing east
    vertices, triangles = boxes_to_mesh(boxes, exact=len(boxes))
    return World("wall", vertices, triangles, (0.0, 0.0, 0.0))


def test_intrinsics_follow_the_settings() -> None:
    cam = DepthCamera(wall_world(3.0), CameraSettings(width=160, height=120, hfov_deg=90.0))
    assert np.allclose(cam.intrinsics, [[80.0, 0, 80.0], [0, 80.0, 60.0], [0, 0, 1]])
    assert cam.render(cam.pose((0, 0, 0), 0.0)).shape == (120, 160)


@pytest.mark.parametrize("d", [0.5, 3.0, 7.5])
def test_flat_wall_reads_its_z_depth_everywhere(d: float) -> None:
    cam = DepthCamera(wall_world(d), CameraSettings())
    depth = cam.render(cam.pose((0.0, 0.0, 0.0), 0.0))
    assert depth.dtype == np.float32
    assert depth[60, 80] == pytest.approx(d, abs=1e-3)
    assert np.all(np.abs(depth - d) < 1e-3)  # corners too: z-depth, not ray length (which is ~1.6 d there)


def test_range_clipping_gives_zero() -> None:
    s = CameraSettings(min_range_m=0.3, max_range_m=8.0)
    for d in (0.2, 8.5):
        cam = DepthCamera(wall_world(d), s)
        assert not cam.render(cam.pose((0, 0, 0), 0.0)).any()
    cam = DepthCamera(wall_world(3.0), s)
    assert not cam.render(cam.pose((0, 0, 0), 180.0)).any()  # facing away: no return


def test_pose_axes() -> None:
    T = camera_pose((1.0, 2.0, 3.0), 90.0, 0.0)
    assert np.allclose(T[:3, 2], [0, 1, 0])  # yaw 90 (ENU) looks north
    assert np.allclose(T[:3, 0], [1, 0, 0])  # ... with east on the right
    assert np.allclose(T[:3, 1], [0, 0, -1])  # image y is down
    assert np.allclose(T[:3, 3], [1, 2, 3])
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3)) and np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    down = camera_pose((0, 0, 0), 0.0, 90.0)
    assert np.allclose(down[:3, 2], [0, 0, -1])  # positive pitch looks down
    tilted = camera_pose((0, 0, 0), 0.0, 30.0)
    assert np.allclose(tilted[:3, 2], [math.cos(math.radians(30)), 0, -0.5])


def test_yaw_90_looks_north_in_the_box_world(box_world: World) -> None:
    cam = DepthCamera(box_world, CameraSettings())
    wall_n, wall_e = 6.0 - 0.15, 8.0 - 0.15  # outer wall faces (shrunk by 0.5 mm in the mesh)
    north = cam.render(cam.pose((2.0, 2.0, 1.5), 90.0))
    east = cam.render(cam.pose((2.0, 2.0, 1.5), 0.0))
    assert north[60, 80] == pytest.approx(wall_n - 2.0, abs=1e-3)
    assert east[60, 80] == pytest.approx(wall_e - 2.0, abs=1e-3)


def test_image_is_not_mirrored() -> None:
    cam = DepthCamera(wall_world(4.0, post=True), CameraSettings())
    depth = cam.render(cam.pose((0.0, 0.0, 0.0), 0.0))
    near = np.abs(depth - 2.0) < 1e-3  # the post's face, at x = 2
    cols = np.flatnonzero(near.any(axis=0))
    assert len(cols) > 0 and cols.min() > 80  # right half: east-facing camera, post to the south (y < 0)
    # columns u with (u + 0.5 - cx) / fx in (0.25, 1.0): the post spans y in [-2, -0.5] at x = 2
    assert cols.min() == 80 + 20 and cols.max() == 159


def test_stereo_noise_matches_the_model() -> None:
    s = CameraSettings(noise="stereo")
    cam = DepthCamera(wall_world(4.0), s, seed=3)
    depth = cam.render(cam.pose((0, 0, 0), 0.0))
    assert depth.all()
    assert depth.std() == pytest.approx(0.002418 * 16, rel=0.2)
    assert depth.mean() == pytest.approx(4.0, abs=0.005)
    again = DepthCamera(wall_world(4.0), s, seed=3).render(cam.pose((0, 0, 0), 0.0))
    assert np.array_equal(depth, again)  # seeded


def test_noise_is_range_gated() -> None:
    s = CameraSettings(noise="stereo", max_range_m=4.0, stereo_sigma_coeff=0.01)
    cam = DepthCamera(wall_world(4.0), s, seed=1)
    depth = cam.render(cam.pose((0, 0, 0), 0.0))
    valid = depth > 0
    assert 0.3 < valid.mean() < 0.7 and depth[valid].max() <= 4.0


def test_frames_agree_with_their_intrinsics_and_pose() -> None:
    from swarm.sensing.frames import DepthFrame
    from swarm.sim.worlds import load_world

    box = load_world("box")
    camera = DepthCamera(box, CameraSettings(width=64, height=48, hfov_deg=80.0), seed=0)
    frames = [camera.frame(i, 0.1 * i, (2.0, 2.0 + 0.5 * i, 1.5), 30.0 * i) for i in range(4)]
    for i, frame in enumerate(frames):
        assert isinstance(frame, DepthFrame)
        assert frame.index == i and frame.t == pytest.approx(0.1 * i)
        assert frame.depth.shape == (48, 64) and frame.depth.dtype == np.float32
        assert np.allclose(frame.K, frames[0].K) and frame.K[0, 2] == 32.0 and frame.K[1, 2] == 24.0
        assert np.allclose(frame.T_world_cam[:3, 3], (2.0, 2.0 + 0.5 * i, 1.5))
        yaw = np.radians(30.0 * i)
        assert np.allclose(frame.T_world_cam[:3, 2], [np.cos(yaw), np.sin(yaw), 0.0])
        # depth, K and pose agree: every valid pixel back-projects onto the world's surface
        points = frame.world_points()
        assert len(points) > 0.9 * frame.depth.size
        assert np.all(box.distance(points) < 2e-3)
