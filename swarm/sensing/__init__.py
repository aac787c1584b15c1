"""Sensor streams in, camera frames out: the first stage of the agent's data flow (sensing -> patches).

A depth camera reaches the agent as ROS 2 messages, whatever carries them (rclpy, Zenoh in the rmw_zenoh or
zenoh-bridge-ros2dds layout, a recorded bag): `sensor_msgs/msg/Image` depth, `sensor_msgs/msg/CameraInfo`
intrinsics, and the vehicle's pose as `nav_msgs/msg/Odometry` or `geometry_msgs/msg/PoseStamped`. This package
decodes them (`messages`, through the `rosbags` typestore: no hand-written CDR), keeps the vehicle's recent poses
and looks one up at an image's timestamp (`poses`), and puts the camera on the vehicle (`frames`: the mounting
transform and the optical frame). Nothing here knows a world mesh or a simulator.
"""
