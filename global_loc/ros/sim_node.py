"""`ros2 run global_loc sim`: the pybullet simulator as a ROS node.

Publishes sensor_msgs/LaserScan on /scan (frame `laser`, mounted on base_link at
x 0.16 m) at `rate_hz`, wheel odometry as
nav_msgs/Odometry on /odom (frame `odom`, child `base_link`; noise and drift set by
`odom_noise`, `odom_drift`), and the robot's true pose as geometry_msgs/PoseStamped on
/sim/true_pose. Drives the wheels from /cmd_vel
(geometry_msgs/Twist); /sim/set_pose (PoseStamped) teleports the robot (the kidnapping).

Optional sensors (off by default: the simulator is then exactly the 2D one):
`rear_laser:=true` publishes /scan_rear (frame `laser_rear`, `rear_fov_deg` 270, at the
back facing back: x -0.25 m, yaw 180 deg, z 0.30 m), at the front laser's rate;
`lidar3d:=true` publishes /points, a sensor_msgs/PointCloud2 of a 16-ring lidar over +-15
deg, 360 deg (frame `lidar`, organized: one row per ring, lowest first, NaN where a ray hit
nothing; x 0, z 0.5 m) at `lidar_rate_hz`, in a world extruded in 3D (walls 2.5 m, tables
0.7 m, cabinets 1.2 m).

The mountings of the sensors it runs go on /tf_static once at start, as
robot_state_publisher puts a URDF's fixed joints there (tf2_msgs/msg/TFMessage, reliable,
transient local, depth 1): the joints base_link -> each frame it stamps, read from
sim/pioneer3dx.urdf (sim/robot.py), the same the rays are cast from. Without tf2_msgs
nothing goes there, and config/sim.yaml (--params-file) tells the server instead.
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import LaserScan, PointCloud2

from ..core.map_io import MapError, load_map_yaml
from ..core.paths import default_map_yaml, sim_params_file
from ..core.transform import Rigid2D, format_pose
from ..io.urdf import joints_to
from ..sim.laser import LaserConfig
from ..sim.lidar3d import Lidar3DConfig
from ..sim.robot import BASE_FRAME, JOINTS, LASER_FRAME, LIDAR_FRAME, REAR_LASER_FRAME
from ..sim.simulator import OdometryNoise, Simulator
from .cloud import cloud_to_msg
from .convert import pose_from_msg, pose_to_msg, scan_to_msg
from .node_main import exit_process, run_node
from .param_types import ParameterError, declare, describe, typed_value
from .tf_static import publish_static_transforms

# Each number's range (inclusive): a rate, a beam count or a range outside it is one line and
# exit code 2 at start, not a timer or a ray caster failing later.
SIM_RANGES = {
    'x': (-1e6, 1e6), 'y': (-1e6, 1e6), 'yaw': (-100.0, 100.0),
    'fov_deg': (1.0, 360.0), 'num_beams': (1, 100000), 'range_min': (0.0, 1000.0), 'range_max': (0.01, 1000.0),
    'noise_std': (0.0, 10.0), 'dropout': (0.0, 1.0), 'rate_hz': (0.01, 1000.0), 'clutter': (0, 1000),
    'seed': (0, 2 ** 31 - 1), 'odom_noise': (0.0, 1.0), 'odom_drift': (-10.0, 10.0), 'rear_fov_deg': (1.0, 360.0),
    'lidar_rate_hz': (0.01, 1000.0),
}


class SimNode(Node):
    def __init__(self):
        super().__init__('global_loc_sim')

        def param(name, value, description):
            """Declared with its range (SIM_RANGES); its value, or ParameterError naming it."""
            lo_hi = SIM_RANGES.get(name)
            problem = declare(self, name, value, describe(value, description, lo_hi))
            if problem:
                raise ParameterError(problem)
            return typed_value(name, value, self.get_parameter(name).value, lo_hi)

        map_yaml = param('map_yaml', default_map_yaml(), 'map the world is built from')
        start = Rigid2D(param('x', 0.0, 'start x, m'), param('y', 0.0, 'start y, m'),
                        param('yaw', 0.0, 'start yaw, rad'))
        laser = LaserConfig(fov_deg=param('fov_deg', 270.0, 'laser field of view, degrees'),
                            num_beams=param('num_beams', 541, 'laser beam count'),
                            range_min=param('range_min', 0.05, 'm'), range_max=param('range_max', 20.0, 'm'),
                            noise_std=param('noise_std', 0.01, 'Gaussian range noise, m'),
                            dropout=param('dropout', 0.01, 'fraction of beams with no return'),
                            rate_hz=param('rate_hz', 10.0, 'scan rate, Hz'))
        if laser.range_max <= laser.range_min:
            raise ParameterError(f'parameter range_max: {laser.range_max} must exceed range_min ({laser.range_min})')
        clutter = param('clutter', 0, 'number of random objects (not in the map) placed in the world')
        seed = param('seed', 0, 'random seed for noise and clutter')
        odometry = OdometryNoise(scale_std=param('odom_noise', 0.02, "odometry: random share of each wheel's travel"),
                                 yaw_drift=param('odom_drift', 0.01, 'odometry: heading drift, rad per metre'))
        rear = (replace(laser, fov_deg=param('rear_fov_deg', 270.0, 'rear laser field of view, degrees'))
                if param('rear_laser', False, 'a rear laser on /scan_rear (frame laser_rear)') else None)
        lidar = (Lidar3DConfig(rate_hz=param('lidar_rate_hz', 10.0, '3D lidar rate, Hz'))
                 if param('lidar3d', False, 'a 16-ring 3D lidar on /points (frame lidar)') else None)
        self.sim = Simulator(load_map_yaml(map_yaml), laser, seed=seed, odometry_noise=odometry, rear_laser=rear,
                             lidar=lidar)
        self.sim.place(start)
        if clutter:
            self.sim.random_clutter(clutter, keep_clear_of=start)
        self.cmd = (0.0, 0.0)
        self.cmd_time = 0.0
        self.scan_pub = self.create_publisher(LaserScan, '/scan', 5)
        self.odom_pub = self.create_publisher(Odometry, '/odom', 10)
        self.pose_pub = self.create_publisher(PoseStamped, '/sim/true_pose',
                                              QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                                         durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.rear_pub = self.create_publisher(LaserScan, '/scan_rear', 5) if rear else None
        if lidar:
            self.cloud_pub = self.create_publisher(PointCloud2, '/points', 2)
            self.create_timer(1.0 / lidar.rate_hz, self.publish_cloud)
        self.create_subscription(Twist, '/cmd_vel', self.on_cmd_vel, 10)
        self.create_subscription(PoseStamped, '/sim/set_pose', self.on_set_pose, 10)
        self.period = 1.0 / laser.rate_hz
        self.create_timer(self.period, self.tick)
        mountings = self.publish_mountings([LASER_FRAME] + [REAR_LASER_FRAME] * bool(rear)
                                           + [LIDAR_FRAME] * bool(lidar))
        self.get_logger().info(f'sim ready: {map_yaml} as {self.sim.num_wall_boxes} boxes, robot at '
                               f'{format_pose(start)}, {clutter} clutter objects, '
                               f'{laser.num_beams} beams over {laser.fov_deg} deg'
                               f'{f", rear laser on /scan_rear over {rear.fov_deg} deg" if rear else ""}'
                               f'{f", 3D lidar on /points at {lidar.rate_hz} Hz" if lidar else ""}; {mountings}')

    def publish_mountings(self, frames: list) -> str:
        """`frames`' mountings on /tf_static (latched, from the URDF); what the log says of them."""
        self.tf_static = publish_static_transforms(self, mounting_joints(frames))
        if self.tf_static is None:
            return f'no tf2_msgs, so no /tf_static: the server finds these sensors\' mountings in {sim_params_file()}'
        return (f'their mountings on /tf_static ({BASE_FRAME} -> {", ".join(frames)}, from the URDF), and in '
                f'{sim_params_file()} (--params-file) for a server without tf')

    def close(self) -> None:
        """Disconnect pybullet (run_node calls it on shutdown)."""
        self.sim.close()

    def on_cmd_vel(self, msg: Twist) -> None:
        """Latest velocity command; it lapses after 0.5 s without a new one."""
        self.cmd = (msg.linear.x, msg.angular.z)
        self.cmd_time = time.monotonic()

    def on_set_pose(self, msg: PoseStamped) -> None:
        """Teleport the robot."""
        pose = pose_from_msg(msg.pose)
        self.sim.place(pose)
        self.get_logger().info(f'teleported to {format_pose(pose)}')

    def tick(self) -> None:
        """Advance physics by one scan period (driving if commanded), publish scan, odometry and truth."""
        v, w = self.cmd if time.monotonic() - self.cmd_time < 0.5 else (0.0, 0.0)
        if v or w:
            self.sim.drive(v, w, self.period)
        scan = self.sim.scan()
        stamp = self.get_clock().now().to_msg()
        msg = scan_to_msg(scan, LASER_FRAME, stamp, self.period)
        truth = PoseStamped()
        truth.header.frame_id = 'map'
        truth.header.stamp = stamp
        truth.pose = pose_to_msg(self.sim.true_pose())
        odom = Odometry()
        odom.header.frame_id, odom.header.stamp, odom.child_frame_id = 'odom', stamp, 'base_link'
        odom.pose.pose = pose_to_msg(self.sim.odom)
        odom.twist.twist.linear.x, odom.twist.twist.angular.z = (float(c) for c in (v, w))
        self.scan_pub.publish(msg)
        if self.rear_pub is not None:
            self.rear_pub.publish(scan_to_msg(self.sim.rear_scan(), REAR_LASER_FRAME, self.get_clock().now().to_msg(),
                                              self.period))
        self.odom_pub.publish(odom)
        self.pose_pub.publish(truth)

    def publish_cloud(self) -> None:
        """One revolution of the 3D lidar at the robot's current pose."""
        points = self.sim.lidar_points()
        rings = np.repeat(np.arange(points.shape[0])[:, None], points.shape[1], axis=1)
        self.cloud_pub.publish(cloud_to_msg(points, LIDAR_FRAME, self.get_clock().now().to_msg(), rings))


def mounting_joints(frames: list) -> list:
    """The URDF's fixed joints from base_link down to each of `frames`, each joint once."""
    joints = {}
    for frame in frames:
        joints.update({j.child: j for j in joints_to(JOINTS, BASE_FRAME, frame)})
    return list(joints.values())


def main(args=None):
    exit_process(run_node(SimNode, startup_errors=(MapError, ParameterError), args=args))


if __name__ == '__main__':
    main()
