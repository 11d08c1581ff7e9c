"""Message fields -> core types, for rclpy messages and rosbags' deserialized ones alike
(the same field names; nothing here imports rclpy). The ROS nodes write messages in
ros/convert.py; both they and the offline commands read them here."""
from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from ..core.cloud import CloudError, CloudField, PackedCloud, cloud_xyz
from ..core.mount3d import Mount3D
from ..core.scan import Scan
from ..core.transform import Rigid2D, yaw_of_quaternion
from ..core.view import SensorReading, ViewError, reading_from_scan


def stamp_seconds(stamp) -> float:
    """A builtin_interfaces/Time as seconds."""
    return stamp.sec + 1e-9 * stamp.nanosec


def scan_from_msg(msg) -> Scan:
    """A sensor_msgs/LaserScan as a core Scan with its header's stamp."""
    return Scan(float(msg.angle_min), float(msg.angle_increment), float(msg.range_min), float(msg.range_max),
                np.asarray(msg.ranges, dtype=float), stamp_seconds(msg.header.stamp), float(msg.angle_max))


def frame_name(frame_id: str) -> str:
    """A frame id as tf2 names it: no leading slash, no surrounding blanks."""
    return frame_id.strip().lstrip('/')


def transform_from_msg(msg) -> tuple[str, str, np.ndarray, np.ndarray]:
    """A geometry_msgs/TransformStamped as (child frame, parent frame, translation x y z,
    rotation quaternion x y z w)."""
    r, q = msg.transform.translation, msg.transform.rotation
    return (frame_name(msg.child_frame_id), frame_name(msg.header.frame_id), np.array([r.x, r.y, r.z], dtype=float),
            np.array([q.x, q.y, q.z, q.w], dtype=float))


def pose_from_msg(msg) -> Rigid2D:
    """A geometry_msgs/Pose's position and heading."""
    return Rigid2D(msg.position.x, msg.position.y, yaw_of_quaternion(msg.orientation))


def packed_from_msg(msg) -> PackedCloud:
    """A sensor_msgs/PointCloud2's layout and data as sent (core.cloud reads and checks it)."""
    fields = tuple(CloudField(str(f.name), int(f.offset), int(f.datatype), int(f.count)) for f in msg.fields)
    return PackedCloud(int(msg.height), int(msg.width), fields, bool(msg.is_bigendian), int(msg.point_step),
                       int(msg.row_step), msg.data, bool(msg.is_dense))


def reading_from_msg(topic: str, is_scan: bool, msg, mount: Callable[[], Mount3D],
                     received: Optional[float] = None) -> SensorReading:
    """A LaserScan (`is_scan`) or PointCloud2 as one sensor's reading; ViewError (a
    ScanError, or the cloud's CloudError said) when it is unusable. `mount()` gives the
    sensor's mounting, asked after the message is read: a message that cannot be used says
    so first, whether or not a mounting is known."""
    if is_scan:
        scan = scan_from_msg(msg)
        return reading_from_scan(topic, scan, mount(), received)
    try:
        points = cloud_xyz(packed_from_msg(msg))
    except CloudError as e:
        raise ViewError(f'cloud unusable: {e}') from None
    return SensorReading(topic, stamp_seconds(msg.header.stamp), points, mount(), received=received)
