"""Other drones in a depth image: the pixel rays that meet a sphere round a peer, masked before mapping unless a
surface hides the peer; the same geometry draws the drones into the simulated images."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.sensing.peers import PeerSighting, mask_peers, pixel_rays, sphere_depth

K = np.array([[80.0, 0.0, 80.0], [0.0, 80.0, 60.0], [0.0, 0.0, 1.0]])
T = np.eye(4)  # camera at the origin looking along +z (optical frame = world here)


def test_a_sphere_straight_ahead_is_met_at_its_near_side_and_covers_its_angular_size() -> None:
    depth = sphere_depth(pixel_rays(K, 120, 160), T, [[0.0, 0.0, 3.0]], 0.2)
    assert depth[60, 80] == pytest.approx(2.8, abs=0.01)
    # angular radius asin(0.2 / 3): about pi * (80 * 0.0668)^2 = 89 pixels
    assert 70 < np.isfinite(depth).sum() < 110
    assert np.isinf(depth[0, 0])
    behind = sphere_depth(pixel_rays(K, 120, 160), T, [[0.0, 0.0, -3.0]], 0.2)
    assert np.isinf(behind).all()


def test_a_peer_in_front_of_the_wall_is_masked_and_one_behind_it_is_not() -> None:
    wall = np.full((120, 160), 5.0, dtype=np.float32)
    wall[:, :10] = 0.0  # no surface there
    masked, count = mask_peers(wall, K, T, [[0.0, 0.0, 3.0]], 0.5)
    assert count > 500 and masked[60, 80] == 0.0 and masked[0, 159] == 5.0 and wall[60, 80] == 5.0
    hidden, none = mask_peers(wall, K, T, [[0.0, 0.0, 7.0]], 0.5)
    assert none == 0 and hidden is wall
    edge, some = mask_peers(wall, K, T, [[-3.4, 0.0, 4.0]], 0.5)  # partly over the pixels with no surface
    assert some > 0 and (edge[:, :10] == 0.0).all()


def test_a_camera_inside_a_peers_sphere_masks_the_whole_image() -> None:
    depth = np.full((12, 16), 2.0, dtype=np.float32)
    k = np.array([[8.0, 0.0, 8.0], [0.0, 8.0, 6.0], [0.0, 0.0, 1.0]])
    masked, count = mask_peers(depth, k, T, [[0.1, 0.0, 0.0]], 0.5)
    assert count == depth.size and not masked.any()


def test_a_heartbeat_places_its_peer_by_its_velocity_at_the_frames_stamp_within_a_second() -> None:
    sighting = PeerSighting((1.0, 2.0, 1.5), (1.5, 0.0, -0.5), heard=100.0)
    assert np.allclose(sighting.at(100.2), [1.3, 2.0, 1.4])
    assert np.allclose(sighting.at(99.9), [0.85, 2.0, 1.55])  # a frame taken before the heartbeat arrived
    assert np.allclose(sighting.at(130.0), [2.5, 2.0, 1.0])  # dead reckoning stops at PREDICT_MAX_S


def _every_ray(rays: np.ndarray, T_world_cam: np.ndarray, centres: np.ndarray, radius: float) -> np.ndarray:
    """sphere_depth without the silhouette boxes: every ray against every sphere."""
    out = np.full(rays.shape[:2], np.inf)
    a = np.einsum("hwk,hwk->hw", rays, rays)
    for c in (centres - T_world_cam[:3, 3]) @ T_world_cam[:3, :3]:
        b = rays @ c
        disc = b * b - a * (c @ c - radius * radius)
        root = np.sqrt(np.maximum(disc, 0.0))
        near = np.where(disc >= 0, (b - root) / a, np.inf)
        far = np.where(disc >= 0, (b + root) / a, np.inf)
        out = np.minimum(out, np.where(near > 0.0, near, np.where(far > 0.0, 0.0, np.inf)))
    return out


def test_testing_only_each_spheres_silhouette_gives_the_depths_of_testing_every_ray() -> None:
    rng = np.random.default_rng(7)
    rays = pixel_rays(K, 120, 160)
    yaw = 0.7
    turned = np.eye(4)
    turned[:3, :3] = [[np.cos(yaw), 0.0, np.sin(yaw)], [0.0, 1.0, 0.0], [-np.sin(yaw), 0.0, np.cos(yaw)]]
    turned[:3, 3] = [0.3, -0.2, 0.5]
    for pose in (T, turned):
        # near and far, beside and behind the camera, one round the camera and one grazing its plane
        centres = np.vstack(
            [rng.uniform(-6.0, 6.0, (40, 3)), pose[:3, 3] + [0.1, 0.0, 0.05], pose[:3, 3] + [2, 0, 0.3]]
        )
        for radius in (0.2, 0.5, 1.5):
            expected = _every_ray(rays, pose, centres, radius)
            assert np.isfinite(expected).sum() > 1000
            np.testing.assert_array_equal(sphere_depth(rays, pose, centres, radius), expected)
