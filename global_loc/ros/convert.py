"""Message <-> core type conversions, shared by the ROS nodes (server, client, sim)."""
from __future__ import annotations

import math

import numpy as np
from geometry_msgs.msg import Pose, PoseWithCovarianceStamped, Quaternion
from nav_msgs.msg import OccupancyGrid
from sensor_msgs.msg import LaserScan

from .map_io import OccupancyMap, from_occupancy_grid
from .scan import Scan
from .transform import Rigid2D


def scan_from_msg(msg: LaserScan) -> Scan:
    return Scan(msg.angle_min, msg.angle_increment, msg.range_min, msg.range_max,
                np.asarray(msg.ranges, dtype=float),
                msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)


def scan_to_msg(scan: Scan, frame_id: str, stamp, scan_time: float = 0.0) -> LaserScan:
    msg = LaserScan(angle_min=float(scan.angle_min), angle_increment=float(scan.angle_increment),
                    angle_max=float(scan.angle_min + scan.angle_increment * (len(scan.ranges) - 1)),
                    scan_time=float(scan_time), range_min=float(scan.range_min), range_max=float(scan.range_max),
                    ranges=[float(r) for r in scan.ranges])
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    return msg


def yaw_to_quaternion(yaw: float) -> Quaternion:
    return Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0))


def quaternion_to_yaw(q: Quaternion) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def pose_to_msg(p: Rigid2D) -> Pose:
    msg = Pose()
    msg.position.x, msg.position.y = float(p.x), float(p.y)
    msg.orientation = yaw_to_quaternion(p.yaw)
    return msg


def pose_from_msg(msg: Pose) -> Rigid2D:
    return Rigid2D(msg.position.x, msg.position.y, quaternion_to_yaw(msg.orientation))


def covariance_6x6(cov3) -> list[float]:
    """(x, y, yaw) 3x3 covariance -> the row-major 6x6 of PoseWithCovariance (x, y, z,
    roll, pitch, yaw). z, roll, pitch get a tiny variance so the matrix stays positive
    definite, as AMCL and robot_localization expect a valid covariance."""
    cov = np.diag([0.0, 0.0, 1e-9, 1e-9, 1e-9, 0.0])
    idx = [0, 1, 5]
    cov3 = np.asarray(cov3, dtype=float)
    for i in range(3):
        for j in range(3):
            cov[idx[i], idx[j]] = cov3[i, j]
    return [float(v) for v in cov.ravel()]


def pose_with_covariance(p: Rigid2D, cov3, frame_id: str, stamp) -> PoseWithCovarianceStamped:
    msg = PoseWithCovarianceStamped()
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    msg.pose.pose = pose_to_msg(p)
    msg.pose.covariance = covariance_6x6(cov3)
    return msg


def map_from_msg(msg: OccupancyGrid) -> OccupancyMap:
    info = msg.info
    origin = Rigid2D(info.origin.position.x, info.origin.position.y, quaternion_to_yaw(info.origin.orientation))
    return from_occupancy_grid(info.width, info.height, info.resolution, origin,
                               np.asarray(msg.data, dtype=np.int16), source=f'OccupancyGrid on {msg.header.frame_id}')
