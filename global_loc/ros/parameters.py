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


def _float_range(lo: float, hi: float) -> dict:
    return {'floating_point_range': [FloatingPointRange(from_value=lo, to_value=hi)]}


def declare_server_parameters(node: Node) -> tuple[ServerSettings, LocalizerConfig]:
    """Declare every parameter on `node` and read them."""
    defaults = LocalizerConfig()

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
        base_frame=param('base_frame', 'base_link', 'robot base frame (for tf2, when available)'))
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
        bnb=bnb)
    return settings, config
