"""ROS 2 sensor messages: depth in both encodings with padding and byte order, intrinsics, poses, and one clear
error for each kind of bad message (never an exception of another kind, never a wrong image)."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.sensing import messages as m


def _depth(seed: int = 0) -> np.ndarray:
    depth = np.random.default_rng(seed).uniform(0.3, 8.0, (12, 16)).astype(np.float32)
    depth[0, :3] = 0.0  # invalid pixels
    return depth


def _wire(message: object, msgtype: str) -> object:
    return m.deserialize(m.serialize(message), msgtype)


@pytest.mark.parametrize(("encoding", "tolerance"), [("32FC1", 0.0), ("16UC1", 0.0005)])
def test_a_depth_image_round_trips_through_cdr_in_either_encoding(encoding: str, tolerance: float) -> None:
    depth = _depth()
    t, back = m.depth_of(_wire(m.image_message(12.25, depth, encoding=encoding), m.IMAGE))
    assert t == pytest.approx(12.25)
    assert back.dtype == np.float32 and back.shape == depth.shape
    assert np.abs(back - depth).max() <= tolerance + 1e-7
    assert np.all(back[0, :3] == 0.0)  # NaN (32FC1) and 0 (16UC1) both read as invalid


def test_row_padding_and_big_endian_pixels_are_honoured() -> None:
    depth = _depth(1)
    msg = m.image_message(1.0, depth, encoding="16UC1")
    h, w = depth.shape
    mm = np.clip(np.rint(depth * 1000), 0, 65535).astype(">u2")
    padded = np.zeros((h, w * 2 + 6), dtype=np.uint8)  # 6 bytes of padding per row
    padded[:, : w * 2] = mm.view(np.uint8).reshape(h, w * 2)
    msg.step, msg.is_bigendian, msg.data = w * 2 + 6, 1, padded.reshape(-1)
    _, back = m.depth_of(_wire(msg, m.IMAGE))
    assert np.abs(back - depth).max() <= 0.0005 + 1e-7


def test_negative_and_infinite_float_depths_are_invalid() -> None:
    depth = _depth(2)
    msg = m.image_message(1.0, depth)
    pixels = depth.copy()
    pixels[1, 1], pixels[2, 2] = -1.0, np.inf
    msg.data = np.frombuffer(pixels.astype("<f4").tobytes(), dtype=np.uint8)
    _, back = m.depth_of(msg)
    assert back[1, 1] == 0.0 and back[2, 2] == 0.0 and back[3, 3] == pytest.approx(depth[3, 3])


@pytest.mark.parametrize(
    ("change", "says"),
    [
        ({"encoding": "rgb8"}, "depth encoding 'rgb8'"),
        ({"step": 10}, "row step 10 B"),
        ({"height": 0}, "0 pixels"),
        ({"height": 13}, "B of data for 13 rows"),
        ({"width": 100_000}, "100000x12"),
    ],
)
def test_a_malformed_depth_image_is_one_clear_error(change: dict, says: str) -> None:
    msg = m.image_message(1.0, _depth())
    for key, value in change.items():
        setattr(msg, key, value)
    with pytest.raises(m.SensorInputError, match=says):
        m.depth_of(msg)


def test_truncated_bytes_are_a_sensor_input_error_not_a_crash() -> None:
    raw = m.serialize(m.image_message(1.0, _depth()))
    for cut in (0, 3, 20, len(raw) // 2):
        with pytest.raises(m.SensorInputError, match="not a sensor_msgs/msg/Image"):
            m.depth_of(m.deserialize(raw[:cut], m.IMAGE))


def test_camera_info_gives_the_pinhole_matrix_and_bad_ones_are_refused() -> None:
    K = np.array([[80.0, 0.0, 79.5], [0.0, 81.0, 59.5], [0.0, 0.0, 1.0]])
    info = _wire(m.camera_info_message(2.0, m.Intrinsics(160, 120, K)), m.CAMERA_INFO)
    got = m.intrinsics_of(info)
    assert (got.width, got.height) == (160, 120) and np.array_equal(got.K, K)
    info.k = np.zeros(9)
    with pytest.raises(m.SensorInputError, match="fx 0"):
        m.intrinsics_of(info)
    info.k = np.full(9, np.nan)
    with pytest.raises(m.SensorInputError, match="9 finite numbers"):
        m.intrinsics_of(info)


def test_odometry_and_pose_stamped_give_the_same_pose() -> None:
    q = np.array([0.0, 0.0, np.sin(0.3), np.cos(0.3)])
    pose = m.Pose(7.5, np.array([1.0, -2.0, 1.5]), q)
    odometry = m.pose_of(_wire(m.odometry_message(pose), m.ODOMETRY))
    types = m.typestore().types
    stamped = types[m.POSE_STAMPED](header=m.header(7.5, "map"), pose=m.odometry_message(pose).pose.pose)
    for got in (odometry, m.pose_of(_wire(stamped, m.POSE_STAMPED))):
        assert got.t == pytest.approx(7.5)
        assert np.allclose(got.position, pose.position) and np.allclose(got.orientation, q)


def test_a_pose_that_is_not_a_rotation_or_not_a_pose_is_refused() -> None:
    bad = m.odometry_message(m.Pose(1.0, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])))
    bad.pose.pose.orientation.w = 0.5
    with pytest.raises(m.SensorInputError, match="norm 0.5"):
        m.pose_of(bad)
    bad.pose.pose.orientation.w, bad.pose.pose.position.x = 1.0, float("nan")
    with pytest.raises(m.SensorInputError, match="position"):
        m.pose_of(bad)
    with pytest.raises(m.SensorInputError, match="not sensor_msgs/msg/Image"):
        m.pose_of(m.image_message(1.0, _depth()))
