"""How the laser sits on the robot base, as far as a 2-D method can use it: where it is,
which way its x axis points, and whether it is upside down.

A laser mounted upside down (roll ~ pi: its z axis points down) turns its beams
clockwise seen from above: its scan, read as an upright laser's, is the mirror image of
the room (confidently wrong on any map without that symmetry). `LaserMount.upright`
gives the scan an upright laser at the same place, x axis along the real one's, would
have taken: every beam angle negated. A laser tilted out of the horizontal plane (roll
or pitch neither ~0 nor ~pi) does not measure the map's distances and is refused.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .limits import MAX_LASER_TILT_DEG
from .mount3d import Mount3D, Mount3DError
from .scan import Scan, ScanError
from .transform import Quaternion, Rigid2D


class MountError(ScanError):
    """The laser's mounting makes its scans unusable here (tilted out of the horizontal plane)."""


@dataclass(frozen=True)
class LaserMount:
    # The laser on the base: its position and the heading of its x axis (seen from above).
    base_T_laser: Rigid2D = field(default_factory=Rigid2D)
    upside_down: bool = False      # its z axis points down: its beam angles run clockwise

    @staticmethod
    def from_rotation(x: float, y: float, base_R_laser) -> 'LaserMount':
        """From the laser's position and its 3x3 rotation in the base frame (z up);
        MountError when its z axis is more than MAX_LASER_TILT_DEG from the vertical."""
        r = np.asarray(base_R_laser, dtype=float)
        if r.shape != (3, 3) or not np.isfinite(r).all() or not all(map(math.isfinite, (x, y))):
            raise MountError(f'laser mounting must be a finite position and 3x3 rotation, got {(x, y)}, {r.tolist()}')
        tilt = math.degrees(math.acos(min(1.0, abs(float(r[2, 2])))))    # of the z axis from the vertical
        if tilt > MAX_LASER_TILT_DEG:
            raise MountError(f'the laser is tilted {tilt:.1f} deg out of the horizontal plane (its roll or pitch '
                             f'is neither ~0 nor ~180 deg; at most {MAX_LASER_TILT_DEG:g} deg): its ranges are '
                             f'not distances in the map plane')
        # The x axis' heading seen from above: for an upside-down laser too (roll pi), where
        # roll-pitch-yaw angles may say the same rotation as pitch pi and a yaw off by pi.
        yaw = math.atan2(r[1, 0], r[0, 0])
        return LaserMount(Rigid2D(float(x), float(y), yaw), bool(r[2, 2] < 0))

    @staticmethod
    def from_mount3d(mount: Mount3D) -> 'LaserMount':
        """A 2D laser's view of its full mounting (MountError when it is tilted)."""
        return LaserMount.from_rotation(mount.x, mount.y, mount.rotation())

    @staticmethod
    def from_quaternion(x: float, y: float, rotation: Quaternion) -> 'LaserMount':
        """From a tf transform's translation (x, y) and rotation (as Mount3D.from_quaternion)."""
        try:
            mount = Mount3D.from_quaternion(x, y, 0.0, rotation)
        except Mount3DError as e:
            raise MountError(f'laser mounting: {e}') from None
        return LaserMount.from_mount3d(mount)

    @staticmethod
    def from_roll_pitch_yaw(x: float, y: float, roll: float, pitch: float, yaw: float) -> 'LaserMount':
        """From a position and ROS roll-pitch-yaw angles (rad; R = Rz(yaw) Ry(pitch) Rx(roll)):
        roll pi with yaw a is an upside-down laser whose x axis points at a."""
        try:
            mount = Mount3D(x, y, 0.0, roll, pitch, yaw)
        except Mount3DError as e:
            raise MountError(f'laser mounting: {e}') from None
        return LaserMount.from_mount3d(mount)

    def upright(self, scan: Scan) -> Scan:
        """`scan` as an upright laser at `base_T_laser` would have taken it: the same scan
        when the laser is upright; every angle negated (angle_max too, so a contradiction
        between the fields is still seen) when it is upside down."""
        if not self.upside_down:
            return scan
        return replace(scan, angle_min=-scan.angle_min, angle_increment=-scan.angle_increment,
                       angle_max=None if scan.angle_max is None else -scan.angle_max)
