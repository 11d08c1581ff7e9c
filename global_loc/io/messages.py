"""Message fields -> core types, for rclpy messages and rosbags' deserialized ones alike
(the same field names; nothing here imports rclpy). The ROS nodes write messages in
ros/convert.py; both they and the offline commands read them here."""
from __future__ import annotations

import numpy as np

from ..core.scan import Scan
from ..core.transform import Rigid2D, yaw_of_quaternion


def stamp_seconds(stamp) -> float:
    """A builtin_interfaces/Time as seconds."""
    return stamp.sec + 1e-9 * stamp.nanosec


def scan_from_msg(msg) -> Scan:
    """A sensor_msgs/LaserScan as a core Scan with its header's stamp."""
    return Scan(float(msg.angle_min), float(msg.angle_increment), float(msg.range_min), float(msg.range_max),
                np.asarray(msg.ranges, dtype=float), stamp_seconds(msg.header.stamp), float(msg.angle_max))


def pose_from_msg(msg) -> Rigid2D:
    """A geometry_msgs/Pose's position and heading."""
    return Rigid2D(msg.position.x, msg.position.y, yaw_of_quaternion(msg.orientation))
