"""The laser's mounting on the robot base: from tf2 where it is installed and has the
transform (a real ROS install), else from the node's laser_x/laser_y/laser_yaw/laser_roll
(tf2 is not on PyPI), so the published pose is the base's, as AMCL expects, and an
upside-down laser's scans are turned upright (core/mount.py)."""
from __future__ import annotations

from rclpy.time import Time

from ..core.mount import LaserMount
from ..core.transform import Rigid2D


class LaserMounting:
    def __init__(self, node, base_frame: str, fallback: Rigid2D, fallback_roll: float = 0.0):
        """`fallback`, `fallback_roll`: the laser_* parameters (roll pi: mounted upside
        down); MountError (a ValueError) when they describe a tilted laser."""
        self.node = node
        self.configure(base_frame, fallback, fallback_roll)
        try:
            import tf2_ros
        except ImportError:
            node.get_logger().info('tf2_ros not available: the laser mounting comes from '
                                   'laser_x/laser_y/laser_yaw/laser_roll')
            self.buffer = None
            return
        self.buffer = tf2_ros.Buffer()
        self.listener = tf2_ros.TransformListener(self.buffer, node)

    def configure(self, base_frame: str, fallback: Rigid2D, fallback_roll: float = 0.0) -> None:
        """New parameters (configure, or a live laser_* change)."""
        self.base_frame = base_frame
        self.fallback = LaserMount.from_roll_pitch_yaw(fallback.x, fallback.y, fallback_roll, 0.0, fallback.yaw)

    def mount(self, laser_frame: str) -> LaserMount:
        """The laser's mounting: from tf2 when it has it, else the parameters. MountError
        (a ScanError) when tf says the laser is tilted out of the horizontal plane."""
        if self.buffer is not None and laser_frame:
            try:
                t = self.buffer.lookup_transform(self.base_frame, laser_frame, Time()).transform
            except Exception as e:   # tf2 raises several types; any means "not known"
                self.node.get_logger().warn(f'no tf {self.base_frame} <- {laser_frame} ({e}); '
                                            'using the laser_* parameters', throttle_duration_sec=10.0)
            else:
                q = t.rotation
                return LaserMount.from_quaternion(t.translation.x, t.translation.y, q.x, q.y, q.z, q.w)
        return self.fallback

    def base_T_laser(self, laser_frame: str) -> Rigid2D:
        """The laser's pose on the base (its x axis' heading); see `mount` for upside-down lasers."""
        return self.mount(laser_frame).base_T_laser
