"""A sensor's full 3D mounting on the robot base (x y z roll pitch yaw, as URDF and tf
give it): where a sensor-frame point lands in the base frame, for 3D lidars and for 2D
lasers mounted any way up. Roll, pitch and yaw are fixed-axis X, Y, Z rotations (R =
Rz(yaw) Ry(pitch) Rx(roll), URDF's rpy), so a laser mounted upside down is roll = pi and
a tilted lidar its pitch. (core.mount.LaserMount is the 2D method's view of one laser.)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .transform import Quaternion, Rigid2D, rotation_of_quaternion

# A scan plane whose normal is within this of vertical is level: its beams, projected to
# the floor, are beams from one origin with their true lengths (the free-space check holds).
LEVEL_TOLERANCE_RAD = math.radians(1.0)


class Mount3DError(ValueError):
    """A mounting cannot be used (wrong number of values, a non-finite one)."""


@dataclass(frozen=True)
class Mount3D:
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0

    def __post_init__(self):
        values = self.as_tuple()
        if not all(isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(v) for v in values):
            raise Mount3DError(f'a mounting needs six finite numbers (x y z roll pitch yaw), got {values}')

    @staticmethod
    def from_values(values) -> 'Mount3D':
        """From a sequence `x y z roll pitch yaw` (a ROS double-array parameter, a CLI flag)."""
        try:
            values = [float(v) for v in values]
        except (TypeError, ValueError) as e:
            raise Mount3DError(f'a mounting needs six numbers (x y z roll pitch yaw): {e}') from None
        if len(values) != 6:
            raise Mount3DError(f'a mounting needs six numbers (x y z roll pitch yaw), got {len(values)}: {values}')
        return Mount3D(*values)

    @staticmethod
    def from_quaternion(x: float, y: float, z: float, rotation: Quaternion) -> 'Mount3D':
        """From a tf transform's translation and rotation (a quaternion with fields x, y, z, w:
        core.transform.Quaternion or a geometry_msgs/Quaternion; normalized here)."""
        q = [rotation.x, rotation.y, rotation.z, rotation.w]
        try:
            matrix = rotation_of_quaternion(*q)
        except ValueError:
            raise Mount3DError(f'a mounting quaternion must be finite and non-zero, got {q}') from None
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = matrix, (x, y, z)
        return Mount3D.from_matrix(m)

    @staticmethod
    def from_matrix(base_T_sensor) -> 'Mount3D':
        """From a 4x4 homogeneous transform base <- sensor (URDF's fixed-axis rpy of its rotation)."""
        m = np.asarray(base_T_sensor, dtype=float)
        r = m[:3, :3]
        if abs(r[2, 0]) > 1.0 - 1e-12:
            # pointing straight up or down: roll and yaw turn about one axis, only their sum
            # is defined, and their sines and cosines are rounding noise - all of it in yaw
            roll, pitch, yaw = 0.0, -math.copysign(math.pi / 2, r[2, 0]), math.atan2(-r[0, 1], r[1, 1])
        else:
            roll, pitch = math.atan2(r[2, 1], r[2, 2]), math.asin(max(-1.0, min(1.0, -r[2, 0])))
            yaw = math.atan2(r[1, 0], r[0, 0])
        return Mount3D(*(float(v) + 0.0 for v in (*m[:3, 3], roll, pitch, yaw)))     # + 0.0: no -0.0

    @staticmethod
    def planar(base_T_laser: Rigid2D, z: float = 0.0) -> 'Mount3D':
        """An upright sensor at a 2D pose on the base (today's laser_x/laser_y/laser_yaw)."""
        return Mount3D(base_T_laser.x, base_T_laser.y, z, 0.0, 0.0, base_T_laser.yaw)

    def describe(self) -> str:
        """The one human-readable form: 'x=0.160 y=0.000 z=0.300 m, roll=0.0 pitch=0.0 yaw=180.0 deg'."""
        return (f'x={self.x:.3f} y={self.y:.3f} z={self.z:.3f} m, roll={math.degrees(self.roll):.1f} '
                f'pitch={math.degrees(self.pitch):.1f} yaw={math.degrees(self.yaw):.1f} deg')

    def as_tuple(self) -> tuple:
        return (self.x, self.y, self.z, self.roll, self.pitch, self.yaw)

    def rotation(self) -> np.ndarray:
        """The 3x3 rotation base <- sensor."""
        cr, sr = math.cos(self.roll), math.sin(self.roll)
        cp, sp = math.cos(self.pitch), math.sin(self.pitch)
        cy, sy = math.cos(self.yaw), math.sin(self.yaw)
        return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                         [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                         [-sp, cp * sr, cp * cr]])

    def matrix(self) -> np.ndarray:
        """The 4x4 homogeneous transform base <- sensor (chains compose by matrix product)."""
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = self.rotation(), (self.x, self.y, self.z)
        return m

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) base-frame points of (N, 3) sensor-frame points, or of (N, 2) ones in the
        sensor's scan plane (z = 0)."""
        p = np.asarray(points, dtype=float)
        if p.ndim != 2 or p.shape[1] not in (2, 3):
            raise Mount3DError(f'points must be (N, 2) or (N, 3), got shape {p.shape}')
        r = self.rotation()
        return p @ r[:, :p.shape[1]].T + np.array([self.x, self.y, self.z])

    def is_level(self) -> bool:
        """Whether the sensor's x-y plane is horizontal (upright or upside down)."""
        return abs(self.rotation()[2, 2]) >= math.cos(LEVEL_TOLERANCE_RAD)

    def upright(self) -> Rigid2D:
        """The 2D frame on the base at the sensor, facing where its x axis points seen
        from above: where a level sensor's beams start, whichever way up it is."""
        r = self.rotation()
        return Rigid2D(self.x, self.y, math.atan2(r[1, 0], r[0, 0]))

    def base_angles(self, angles: np.ndarray) -> np.ndarray:
        """Directions (yaw on the base) of scan-plane beams at sensor-frame `angles`."""
        a = np.asarray(angles, dtype=float)
        r = self.rotation()
        return np.arctan2(r[1, 0] * np.cos(a) + r[1, 1] * np.sin(a), r[0, 0] * np.cos(a) + r[0, 1] * np.sin(a))
