"""The laser's mounting on the robot base: from tf2 where it is installed and has the
transform (a real ROS install), else from the node's laser_x/laser_y/laser_yaw (tf2 is
not on PyPI), so the published pose is the base's, as AMCL expects."""
from __future__ import annotations

from rclpy.time import Time

from ..core.transform import Rigid2D
from .convert import quaternion_to_yaw


class LaserMounting:
    def __init__(self, node, base_frame: str, fallback: Rigid2D):
        self.node, self.base_frame, self.fallback = node, base_frame, fallback
        try:
            import tf2_ros
        except ImportError:
            node.get_logger().info('tf2_ros not available: the laser mounting comes from laser_x/laser_y/laser_yaw')
            self.buffer = None
            return
        self.buffer = tf2_ros.Buffer()
        self.listener = tf2_ros.TransformListener(self.buffer, node)

    def base_T_laser(self, laser_frame: str) -> Rigid2D:
        """The laser's pose on the base: from tf2 when it has it, else the parameters."""
        if self.buffer is not None and laser_frame:
            try:
                t = self.buffer.lookup_transform(self.base_frame, laser_frame, Time()).transform
                return Rigid2D(t.translation.x, t.translation.y, quaternion_to_yaw(t.rotation))
            except Exception as e:   # tf2 raises several types; any means "not known"
                self.node.get_logger().warn(f'no tf {self.base_frame} <- {laser_frame} ({e}); '
                                            'using the laser_* parameters')
        return self.fallback
