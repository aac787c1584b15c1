"""`FrameAssembler`: images, camera info and poses in any order in, frames with the pose at each image's stamp
out; everything it cannot use counted under its reason and kept out of the frames."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from swarm.config import load_config
from swarm.sensing import messages as m
from swarm.sensing.frames import mount_transform
from swarm.sensing.poses import PoseBuffer
from swarm.sensing.stream import FrameAssembler, StreamInbox

K = np.array([[8.0, 0.0, 7.5], [0.0, 8.0, 5.5], [0.0, 0.0, 1.0]])
DEPTH = np.full((12, 16), 2.0, dtype=np.float32)


def _pose(t: float, x: float) -> m.Pose:
    return m.Pose(t, np.array([x, 0.0, 1.5]), Rotation.identity().as_quat())


def _assembler(**kwargs: object) -> FrameAssembler:
    out = FrameAssembler(mount_transform((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), PoseBuffer(max_gap_s=0.5), **kwargs)
    out.on_camera_info(m.serialize(m.camera_info_message(0.0, m.Intrinsics(16, 12, K))))
    return out


def test_an_image_waits_for_the_pose_after_its_stamp_and_gets_the_interpolated_pose() -> None:
    frames = _assembler()
    frames.on_pose(m.serialize(m.odometry_message(_pose(1.0, 0.0))), m.ODOMETRY)
    frames.on_image(m.serialize(m.image_message(1.25, DEPTH)))
    assert frames.take() == []  # the pose after 1.25 s has not come yet
    frames.on_pose(_pose(1.5, 1.0))
    (frame,) = frames.take()
    assert frame.t == pytest.approx(1.25) and frame.T_world_cam[0, 3] == pytest.approx(0.5)
    assert frame.K[0, 2] == 8.0  # ROS's 7.5 in the mapper's pixel-centre convention
    assert np.array_equal(frame.depth, DEPTH) and not frames.dropped


def test_unusable_input_is_counted_by_reason_and_never_becomes_a_frame() -> None:
    frames = FrameAssembler(np.eye(4), PoseBuffer(max_gap_s=0.2, max_hold_s=0.0), max_wait_s=0.15)
    frames.on_image(m.image_message(1.0, DEPTH))  # no camera info yet
    frames.on_camera_info(b"\x00\x01\x00\x00junk")
    frames.on_camera_info(m.camera_info_message(0.0, m.Intrinsics(16, 12, K)))
    frames.on_image(m.image_message(1.0, np.zeros((6, 8), np.float32)))  # not the camera info's size
    frames.on_image(b"\x00\x01\x00\x00\x01")
    frames.on_pose(b"\x00\x01", m.ODOMETRY)
    frames.on_pose(_pose(2.0, 0.0))
    frames.on_pose(_pose(1.0, 0.0))  # older than the newest
    frames.on_image(m.image_message(1.0, DEPTH))  # before the first pose: the stream was starting
    frames.on_pose(_pose(3.0, 0.0))
    frames.on_image(m.image_message(2.5, DEPTH))  # between poses 1 s apart
    for t in (4.0, 4.1, 4.2):  # no pose comes: the image waiting more than 0.15 s of stamps is let go
        frames.on_image(m.image_message(t, DEPTH))
    assert frames.take() == []
    assert dict(frames.dropped) == {
        "image before camera info": 1,
        "bad camera info": 1,
        "image size differs from camera info": 1,
        "bad image": 1,
        "bad pose": 1,
        "pose out of order": 1,
        "pose early": 1,
        "pose gap": 1,
        "no pose in time": 1,
    }
    frames.on_pose(_pose(4.05, 0.0))
    frames.on_pose(_pose(4.15, 0.0))
    assert [f.t for f in frames.take()] == pytest.approx([4.1])  # 4.2 still waits for a later pose


def test_an_image_waits_for_its_pose_a_time_not_a_count_of_images() -> None:
    """At 30 Hz as at 10 Hz, an image waits for the pose after its stamp while the stream behind it spans at most
    max_wait_s; max_pending bounds the memory of a faster stream."""
    for rate_hz in (10.0, 30.0):
        frames = FrameAssembler(np.eye(4), PoseBuffer(max_gap_s=2.0, max_hold_s=0.0), max_wait_s=0.5)
        frames.on_camera_info(m.camera_info_message(0.0, m.Intrinsics(16, 12, K)))
        frames.on_pose(_pose(0.0, 0.0))
        stamps = [0.01 + i / rate_hz for i in range(int(0.5 * rate_hz))]
        for t in stamps:
            frames.on_image(m.image_message(t, DEPTH))
        assert dict(frames.dropped) == {}, rate_hz  # all waiting: the stamps span less than 0.5 s
        frames.on_image(m.image_message(stamps[0] + 0.5 + 0.5 / rate_hz, DEPTH))  # the first waited too long
        assert dict(frames.dropped) == {"no pose in time": 1}, rate_hz
        frames.on_pose(_pose(2.0, 1.0))
        assert len(frames.take()) == len(stamps)
    frames = FrameAssembler(np.eye(4), PoseBuffer(), max_wait_s=10.0, max_pending=3)
    frames.on_camera_info(m.camera_info_message(0.0, m.Intrinsics(16, 12, K)))
    frames.on_pose(_pose(0.0, 0.0))
    for t in (0.1, 0.2, 0.3, 0.4):
        frames.on_image(m.image_message(t, DEPTH))
    assert dict(frames.dropped) == {"no pose in time": 1}


def _colour_image(t: float) -> bytes:
    """A well-formed rgb8 image of the camera info's size: a colour topic where the depth topic should be."""
    return m.serialize(
        m.typestore().types[m.IMAGE](
            header=m.header(t, "camera_optical"),
            height=12,
            width=16,
            encoding="rgb8",
            is_bigendian=0,
            step=16 * 3,
            data=np.zeros(12 * 16 * 3, dtype=np.uint8),
        )
    )


def test_a_colour_image_and_a_stale_one_are_counted_by_their_reasons_and_never_become_frames() -> None:
    """Through a live source's inbox, as CDR bytes: after 12 s of odometry at 50 Hz (more than the pose buffer
    keeps), an image stamped 11.5 s before the newest pose is stale; an rgb8 image is no depth."""
    inbox = StreamInbox(load_config().camera.stream, np.eye(4))
    (info_topic, info_type, on_info), (pose_topic, pose_type, on_pose), (depth_topic, image_type, on_image) = (
        inbox.topics()
    )
    inbox.deliver(info_topic, info_type, on_info, m.serialize(m.camera_info_message(0.0, m.Intrinsics(16, 12, K))))
    for i in range(600):
        pose = m.serialize(m.odometry_message(_pose(100.0 + i / 50, 0.01 * i)))
        inbox.deliver(pose_topic, pose_type, on_pose, pose)
    inbox.deliver(depth_topic, image_type, on_image, m.serialize(m.image_message(100.5, DEPTH)))
    inbox.deliver(depth_topic, image_type, on_image, _colour_image(111.9))
    assert inbox.wait_frame(0.0) is None
    inbox.deliver(depth_topic, image_type, on_image, m.serialize(m.image_message(111.9, DEPTH)))  # the same, in depth
    frame = inbox.wait_frame(0.0)
    assert frame is not None and frame.t == pytest.approx(111.9)
    assert inbox.counters() == {"frames": 1, "not_taken": 0, "pose stale": 1, "unknown encoding": 1}
