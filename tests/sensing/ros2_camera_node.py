"""A ROS 2 node (rclpy, Fast DDS) standing in for a drone's camera driver and autopilot bridge: it renders depth
from a world mesh along a tilting flight and publishes sensor_msgs/Image, CameraInfo and nav_msgs/Odometry for
`seconds`. Run by tests/sensing/test_ros2_source.py in a process of its own: python ros2_camera_node.py SECONDS."""

from __future__ import annotations

import sys
import time

import numpy as np
import rclpy
from nav_msgs.msg import Odometry
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image

from swarm.config import load_config
from swarm.sensing import messages as m
from swarm.sensing.frames import camera_mount, camera_to_world
from swarm.sim.camera import DepthCamera
from swarm.sim.sensors import body_pose
from swarm.sim.worlds import load_world
from tests.sensing.flight import flight


def main(seconds: float) -> None:
    config = load_config()
    camera = DepthCamera(load_world("office"), config.camera)
    K = np.array(camera.intrinsics)
    K[0, 2] -= 0.5
    K[1, 2] -= 0.5
    info = m.Intrinsics(config.camera.width, config.camera.height, K)
    rclpy.init()
    node = rclpy.create_node("test_camera")
    images = node.create_publisher(Image, "/camera/depth/image_rect_raw", qos_profile_sensor_data)
    infos = node.create_publisher(CameraInfo, "/camera/depth/camera_info", qos_profile_sensor_data)
    odometry = node.create_publisher(Odometry, "/odom", qos_profile_sensor_data)
    started = time.time()
    tick = 0
    while time.time() - started < seconds:
        t = time.time()
        pose = body_pose(t, *flight(t - started))
        odometry.publish(m.serialize(m.odometry_message(pose)))
        if tick % 5 == 0:
            depth = camera.render(camera_to_world(pose, camera_mount(config.camera)))
            infos.publish(m.serialize(m.camera_info_message(t, info)))
            images.publish(m.serialize(m.image_message(t, depth, encoding="16UC1")))
        tick += 1
        time.sleep(max(0.0, started + tick / 50 - time.time()))  # 50 Hz odometry, 10 Hz camera
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main(float(sys.argv[1]))
