"""What an input variable reads from a ROS 2 message (docs/reference/config.md,
"Inputs from real robots"): field paths with array elements, reductions over
arrays, message stamps and arrival, service calls and action goals.

The config validates variables against these modules, and the daemon and
``replay`` read messages through the same readers, so online and offline agree.
No rclpy here: only rosidl's generated message classes (or rosbags' dataclasses,
which have the same attribute names).
"""
