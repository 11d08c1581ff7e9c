"""2-D rigid transforms: the one place where frame changes are computed.

`Rigid2D(x, y, yaw)` is the pose of a child frame in a parent frame; `a * b` composes
(parent_T_child * child_T_grandchild), `inverse()` inverts, `apply()` maps points.
Everything else in global_loc (pixel frames, matches, laser mounting) composes these
instead of writing out trigonometry; quaternions are read and made here alone. Also
here: how far one pose is from another, the success test every evaluation uses, and the
one way a pose is printed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np


class Quaternion(NamedTuple):
    """A rotation quaternion by geometry_msgs/Quaternion's fields (x, y, z, w): wherever one
    is taken, such a message of rclpy or rosbags is taken alike."""
    x: float
    y: float
    z: float
    w: float


def yaw_of_quaternion(q) -> float:
    """The heading (rotation about z) of a quaternion with fields x, y, z, w: a
    geometry_msgs/Quaternion of rclpy or rosbags alike."""
    return rpy_of_quaternion(q.x, q.y, q.z, q.w)[2]


def rpy_of_quaternion(qx: float, qy: float, qz: float, qw: float) -> tuple[float, float, float]:
    """URDF's fixed-axis (roll, pitch, yaw) of a unit quaternion, pitch clamped at +-90 deg."""
    roll = math.atan2(2.0 * (qw * qx + qy * qz), 1.0 - 2.0 * (qx * qx + qy * qy))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (qw * qy - qz * qx))))
    yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return roll, pitch, yaw


def quaternion_of_rpy(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """The unit quaternion (x, y, z, w) of URDF's fixed-axis (roll, pitch, yaw), R = Rz(yaw)
    Ry(pitch) Rx(roll): what tf carries for a URDF joint's origin."""
    cr, sr = math.cos(roll / 2.0), math.sin(roll / 2.0)
    cp, sp = math.cos(pitch / 2.0), math.sin(pitch / 2.0)
    cy, sy = math.cos(yaw / 2.0), math.sin(yaw / 2.0)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


def rotation_of_quaternion(qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """The 3x3 rotation of a quaternion, normalized here (no detour through angles, so a
    sensor pointing straight down keeps its heading); ValueError when it is not finite or zero."""
    q = np.array([qx, qy, qz, qw], dtype=float)
    norm = float(np.linalg.norm(q))
    if not math.isfinite(norm) or norm < 1e-9:
        raise ValueError(f'a rotation quaternion must be finite and non-zero, got {q.tolist()}')
    x, y, z, w = q / norm
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def normalize_angle(a):
    """Wrap an angle (scalar or array) to [-pi, pi)."""
    return (np.asarray(a) + math.pi) % (2 * math.pi) - math.pi if isinstance(a, np.ndarray) \
        else (a + math.pi) % (2 * math.pi) - math.pi


@dataclass(frozen=True)
class Rigid2D:
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0

    def is_finite(self) -> bool:
        return all(map(math.isfinite, (self.x, self.y, self.yaw)))

    @staticmethod
    def from_matrix(m) -> 'Rigid2D':
        """From a 3x3 homogeneous matrix whose linear part is a rotation (or a rotation
        times a positive scale, which is divided out)."""
        m = np.asarray(m, dtype=float)
        return Rigid2D(float(m[0, 2]), float(m[1, 2]), math.atan2(m[1, 0], m[0, 0]))

    def matrix(self) -> np.ndarray:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.array([[c, -s, self.x], [s, c, self.y], [0.0, 0.0, 1.0]])

    def __mul__(self, other: 'Rigid2D') -> 'Rigid2D':
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return Rigid2D(self.x + c * other.x - s * other.y,
                       self.y + s * other.x + c * other.y,
                       normalize_angle(self.yaw + other.yaw))

    def inverse(self) -> 'Rigid2D':
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return Rigid2D(-(c * self.x + s * self.y), s * self.x - c * self.y, -self.yaw)

    def apply(self, points) -> np.ndarray:
        """Map an (N, 2) array of points from the child frame to the parent frame."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.stack([self.x + c * p[:, 0] - s * p[:, 1],
                         self.y + s * p[:, 0] + c * p[:, 1]], axis=1)

    def distance_to(self, other: 'Rigid2D') -> tuple[float, float]:
        """(position error in metres, absolute heading error in radians)."""
        return (math.hypot(self.x - other.x, self.y - other.y),
                abs(normalize_angle(self.yaw - other.yaw)))

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.yaw)

    def as_dict(self) -> dict:
        """{'x', 'y', 'yaw'} rounded for JSON output (0.1 mm, 1e-5 rad)."""
        return {'x': round(self.x, 4), 'y': round(self.y, 4), 'yaw': round(self.yaw, 5)}


def covariance_of_composition(pose: Rigid2D, covariance, child: Rigid2D) -> np.ndarray:
    """Covariance (x, y, yaw) of `pose * child` when `pose` has `covariance` and `child`
    is exact (e.g. laser pose -> base pose): first-order, J C J^T."""
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    j = np.array([[1.0, 0.0, -s * child.x - c * child.y],
                  [0.0, 1.0, c * child.x - s * child.y],
                  [0.0, 0.0, 1.0]])
    return j @ np.asarray(covariance, dtype=float) @ j.T


# A localization is right when it is this close to the truth (the thesis's criterion).
CORRECT_XY_M = 0.2
CORRECT_YAW_DEG = 5.0


def pose_error(estimate: Rigid2D, truth: Rigid2D) -> tuple[float, float]:
    """(metres, degrees) between two poses."""
    d, a = estimate.distance_to(truth)
    return d, math.degrees(a)


def pose_correct(estimate: Rigid2D, truth: Rigid2D, max_xy: float = CORRECT_XY_M,
                 max_yaw_deg: float = CORRECT_YAW_DEG) -> bool:
    """Whether `estimate` is within max_xy metres and max_yaw_deg degrees of `truth`."""
    d, a = pose_error(estimate, truth)
    return bool(d < max_xy and a < max_yaw_deg)


def format_pose(p: Rigid2D) -> str:
    """The one human-readable form of a pose: 'x=1.234 y=5.678 yaw=90.0 deg'."""
    return f'x={p.x:.3f} y={p.y:.3f} yaw={math.degrees(p.yaw):.1f} deg'
