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
