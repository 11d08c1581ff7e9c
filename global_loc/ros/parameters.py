"""The server's ROS parameters: each declared once, with its description and range, and
turned into the core's LocalizerConfig plus the node's own settings."""
from __future__ import annotations

from dataclasses import dataclass

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node

from ..core.localizer import LocalizerConfig
from ..core.matchers import BranchAndBoundOptions, method_names
from ..core.matchers.bnb.options import option_fields
from ..core.paths import default_map_yaml
from ..core.supervisor import SupervisorConfig
from ..core.transform import Rigid2D


@dataclass(frozen=True)
class ServerSettings:
    autostart: bool
    map_yaml: str
    use_map_topic: bool
    map_topic: str
    scan_topic: str
    initialpose_topic: str
    scan_timeout_s: float
    map_frame: str
    base_frame: str
    pose_topic: str
    odom_topic: str
    cmd_vel_topic: str
    rotate_speed: float
    health_period_s: float
    relocalize_resolve_by_motion_s: float


def _float_range(lo: float, hi: float) -> dict:
    return {'floating_point_range': [FloatingPointRange(from_value=lo, to_value=hi)]}


def declare_server_parameters(node: Node) -> tuple[ServerSettings, LocalizerConfig, SupervisorConfig]:
    """Declare every parameter on `node` and read them."""
    defaults = LocalizerConfig()
    watch = SupervisorConfig()

    def param(name, value, description, **ranges):
        return node.declare_parameter(name, value, ParameterDescriptor(description=description, **ranges)).value

    settings = ServerSettings(
        autostart=param('autostart', True, 'configure and activate on start (false: a lifecycle manager does)'),
        map_yaml=param('map_yaml', '', 'nav2 map YAML to localize in (empty: the shipped map)') or default_map_yaml(),
        use_map_topic=param('use_map_topic', False, 'take the map from an OccupancyGrid topic instead of map_yaml'),
        map_topic=param('map_topic', '/map', 'OccupancyGrid topic (transient local, like nav2 map_server)'),
        scan_topic=param('scan_topic', '/scan', 'sensor_msgs/LaserScan topic'),
        initialpose_topic=param('initialpose_topic', '/initialpose', 'where successful poses are published'),
        scan_timeout_s=param('scan_timeout_s', 5.0, 'how long a goal waits for a fresh scan, s',
                             **_float_range(0.1, 600.0)),
        map_frame=param('map_frame', 'map', 'frame of the published pose'),
        base_frame=param('base_frame', 'base_link', 'robot base frame (for tf2, when available)'),
        pose_topic=param('pose_topic', '/amcl_pose', "the localizer's pose (PoseWithCovarianceStamped), watched"),
        odom_topic=param('odom_topic', '/odom', 'nav_msgs/Odometry: moves the watched pose and the hypotheses'),
        cmd_vel_topic=param('cmd_vel_topic', '/cmd_vel', 'where rotate_in_place turns the robot (Twist)'),
        rotate_speed=param('rotate_speed', 0.4, 'rotate_in_place turn rate, rad/s', **_float_range(0.05, 2.0)),
        health_period_s=param('health.period_s', 0.5, 'how often the fit at the watched pose is checked, s',
                              **_float_range(0.05, 60.0)),
        relocalize_resolve_by_motion_s=param('relocalize.resolve_by_motion_s', 0.0,
                                             'automatic relocalization: how long an ambiguous answer may be '
                                             'followed while the robot moves (0: not)'))
    supervisor = SupervisorConfig(
        auto_relocalize=param('auto_relocalize', watch.auto_relocalize,
                              'relocalize on its own at start (no pose yet) and when lost; publishes poses'),
        degraded_fit=param('health.degraded_fit', watch.degraded_fit, 'fit below which the state is degraded'),
        lost_fit=param('health.lost_fit', watch.lost_fit, 'fit below which, for health.lost_after_s, it is lost'),
        lost_after_s=param('health.lost_after_s', watch.lost_after_s, 'how long the fit must stay low to be lost'),
        start_delay_s=param('relocalize.start_delay_s', watch.start_delay_s,
                            'with no pose ever received: wait this long after activation'),
        min_interval_s=param('relocalize.min_interval_s', watch.min_interval_s, 'between two relocalizations, s'),
        max_attempts=param('relocalize.max_attempts', watch.max_attempts,
                           'relocalizations in a row without recovering, then stay lost'),
        settle_s=param('relocalize.settle_s', watch.settle_s,
                       'after publishing, how long the localizer has to take the pose, s'))
    bnb = BranchAndBoundOptions(**{name: param(f'bnb.{name}', default, f'bnb matcher: {help_text}')
                                   for name, _, default, help_text in option_fields()})
    config = LocalizerConfig(
        method=param('method', defaults.method, f'default matcher: {", ".join(method_names())}'),
        angle_step_deg=param('angle_step_deg', defaults.angle_step_deg,
                             'rotation step of the template matcher, degrees', **_float_range(0.1, 180.0)),
        opening_kernel=param('opening_kernel', defaults.opening_kernel,
                             'opening kernel of the local map, pixels (0 = off)',
                             integer_range=[IntegerRange(from_value=0, to_value=31, step=1)]),
        covariance_xy=param('covariance_xy', defaults.covariance_xy,
                            'x and y variance published with the thesis matchers, m^2', **_float_range(1e-6, 100.0)),
        covariance_yaw=param('covariance_yaw', defaults.covariance_yaw,
                             'yaw variance published with the thesis matchers, rad^2', **_float_range(1e-6, 10.0)),
        base_T_laser=Rigid2D(param('laser_x', 0.0, 'laser position on the base, m (used without tf2)'),
                             param('laser_y', 0.0, 'laser position on the base, m (used without tf2)'),
                             param('laser_yaw', 0.0, 'laser heading on the base, rad (used without tf2)')),
        max_search_s=param('max_search_s', 5.0, 'seconds a search may take; then the goal ends "search '
                           'incomplete" with what was explored (a goal always ends)', **_float_range(0.01, 1e6)),
        bnb=bnb)
    return settings, config, supervisor
