"""Core types -> messages, shared by the ROS nodes (server, client, sim), and the readers
of io/messages.py (which need no rclpy: the offline commands read bags with them)."""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Pose, PoseArray, PoseWithCovarianceStamped, Quaternion
from nav_msgs.msg import OccupancyGrid
from sensor_msgs.msg import LaserScan

from global_loc_interfaces.action import Localize

from ..core.localizer import LocalizationResult
from ..core.map_io import OccupancyMap, from_occupancy_grid
from ..core.outcome import Outcome
from ..core.scan import Scan
from ..core.transform import Rigid2D, quaternion_of_rpy, yaw_of_quaternion

# the readers serve rclpy and rosbags messages alike (io/messages.py); the nodes import them from here too
from ..io.messages import pose_from_msg, scan_from_msg, stamp_seconds  # noqa: F401


def scan_to_msg(scan: Scan, frame_id: str, stamp, scan_time: float = 0.0) -> LaserScan:
    msg = LaserScan(angle_min=float(scan.angle_min), angle_increment=float(scan.angle_increment),
                    angle_max=float(scan.angle_min + scan.angle_increment * (len(scan.ranges) - 1)),
                    scan_time=float(scan_time), range_min=float(scan.range_min), range_max=float(scan.range_max),
                    ranges=[float(r) for r in scan.ranges])
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    return msg


def yaw_to_quaternion(yaw: float) -> Quaternion:
    """The message of a heading's quaternion (core/transform owns the formula)."""
    x, y, z, w = quaternion_of_rpy(0.0, 0.0, yaw)
    return Quaternion(x=x, y=y, z=z, w=w)


def pose_to_msg(p: Rigid2D) -> Pose:
    msg = Pose()
    msg.position.x, msg.position.y = float(p.x), float(p.y)
    msg.orientation = yaw_to_quaternion(p.yaw)
    return msg


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
    origin = Rigid2D(info.origin.position.x, info.origin.position.y, yaw_of_quaternion(info.origin.orientation))
    return from_occupancy_grid(info.width, info.height, info.resolution, origin,
                               np.asarray(msg.data, dtype=np.int16), source=f'OccupancyGrid on {msg.header.frame_id}')


def map_to_msg(occupancy_map: OccupancyMap, frame_id: str = 'map') -> OccupancyGrid:
    """An OccupancyGrid of an OccupancyMap (rows bottom-up, as ROS has them)."""
    msg = OccupancyGrid()
    msg.header.frame_id = frame_id
    msg.info.resolution = float(occupancy_map.resolution)
    msg.info.width, msg.info.height = occupancy_map.width, occupancy_map.height
    msg.info.origin = pose_to_msg(occupancy_map.origin)
    msg.data = np.flipud(occupancy_map.occupancy).astype(np.int8).ravel().tolist()
    return msg


def result_to_msg(result: LocalizationResult, frame_id: str, stamp, elapsed_s: float) -> Localize.Result:
    """The action result for a localization the matcher finished (stamped with the scan's time)."""
    out = Localize.Result(outcome=int(result.outcome), success=result.success, message=result.message,
                          score=float(result.score), confidence=float(result.confidence), elapsed_s=float(elapsed_s))
    out.hypotheses = PoseArray()
    out.hypotheses.header.frame_id = frame_id
    out.hypotheses.header.stamp = stamp
    out.hypotheses.poses = [pose_to_msg(h.pose) for h in result.hypotheses]
    out.hypothesis_scores = [float(h.score) for h in result.hypotheses]
    out.map, out.hypothesis_maps = result.map, [h.map for h in result.hypotheses]
    if result.pose is not None:
        out.pose = pose_with_covariance(result.pose, result.covariance, frame_id, stamp)
    return out


def ended_result(outcome: Outcome, message: str) -> Localize.Result:
    """The action result for a goal the server ended before the matcher did (busy, no scan, ...)."""
    return Localize.Result(outcome=int(outcome), success=False, message=message)
