"""The pose at an image's stamp: interpolated between bracketing samples, held briefly past the newest, and
refused (with the reason) when stale, too far ahead or across a gap."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from swarm.sensing.messages import Pose
from swarm.sensing.poses import Miss, PoseBuffer, slerp


def _pose(t: float, x: float, yaw_deg: float) -> Pose:
    return Pose(t, np.array([x, 0.0, 1.5]), Rotation.from_euler("z", yaw_deg, degrees=True).as_quat())


def _yaw(pose: Pose) -> float:
    return float(Rotation.from_quat(pose.orientation).as_euler("xyz", degrees=True)[2])


def test_a_stamp_between_two_samples_gets_the_interpolated_position_and_attitude() -> None:
    poses = PoseBuffer(max_gap_s=0.5)
    poses.add(_pose(1.0, 0.0, 10.0))
    poses.add(_pose(1.2, 1.0, 50.0))
    got = poses.at(1.05)
    assert isinstance(got, Pose)
    assert got.position[0] == pytest.approx(0.25) and _yaw(got) == pytest.approx(20.0)
    assert got.t == 1.05


def test_the_newest_pose_is_held_briefly_and_no_longer() -> None:
    poses = PoseBuffer(max_hold_s=0.05)
    poses.add(_pose(1.0, 0.0, 0.0))
    assert isinstance(poses.at(1.04), Pose)
    assert poses.at(1.06) is Miss.FUTURE


def test_stale_gapped_and_empty_lookups_say_why() -> None:
    poses = PoseBuffer(capacity=3, max_gap_s=0.25)
    assert poses.at(1.0) is Miss.EMPTY
    poses.add(_pose(1.0, 1.0, 0.0))
    assert poses.at(0.9) is Miss.EARLY  # before the first pose ever received: the stream was starting
    for t in (1.1, 1.2, 2.0):  # capacity 3: the sample at 1.0 falls out
        poses.add(_pose(t, t, 0.0))
    assert poses.at(1.05) is Miss.STALE
    assert poses.at(1.5) is Miss.GAP  # 1.2 to 2.0: 0.8 s without a pose
    assert isinstance(poses.at(1.15), Pose)


def test_a_sample_out_of_order_is_counted_and_dropped() -> None:
    poses = PoseBuffer()
    assert poses.add(_pose(2.0, 0.0, 0.0)) and not poses.add(_pose(1.0, 5.0, 0.0))
    assert poses.out_of_order == 1 and len(poses) == 1


def test_slerp_takes_the_short_way_round() -> None:
    q0 = Rotation.from_euler("z", 170, degrees=True).as_quat()
    q1 = -Rotation.from_euler("z", -170, degrees=True).as_quat()  # the same as -170 deg, other hemisphere
    mid = Rotation.from_quat(slerp(q0, q1, 0.5)).as_euler("xyz", degrees=True)[2]
    assert abs(abs(mid) - 180.0) < 1e-6
    assert np.allclose(slerp(q0, q0, 0.3), q0)
