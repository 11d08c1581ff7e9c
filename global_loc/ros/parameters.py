"""The server's ROS parameters, nav2's policy: each declared once, with its description
and range; all read in on_configure (cleanup -> set -> configure applies new values,
map_yaml included); those safe to change while running (`live`) apply to the next
request when set; setting another while configured is refused with the reason (how to
apply it). An invalid value makes configure fail with one line naming it - never a
traceback, never a configured node whose every goal fails.

`ServerConfig` is one immutable snapshot of them all; the node swaps it whole.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.exceptions import ParameterUninitializedException
from rclpy.parameter import Parameter

from ..core import limits
from ..core.localizer import LocalizerConfig
from ..core.map_set import MapSetError, map_name, named_paths
from ..core.matchers import TRACKER_METHOD, BranchAndBoundOptions, method_names, resolve_method
from ..core.matchers.bnb import option_fields, option_range
from ..core.mount import LaserMount, MountError
from ..core.mount3d import Mount3D
from ..core.paths import default_map_yaml
from ..core.request import BOUNDS, RequestDefaults
from ..core.supervisor import SupervisorConfig
from ..core.transform import Rigid2D
from ..core.view import ViewConfig
from .param_types import ParameterError, declare, describe, typed_value
from .sensors import check_mount_value, sensor_specs

_L, _S, _V = LocalizerConfig(), SupervisorConfig(), ViewConfig()
# the thesis's matchers, cheap to precompute (a blurred map image; ORB where SURF is missing);
# SIFT's pyramid costs ~240 bytes a map cell: named in `methods` when wanted
PREPARED_METHODS = ('template_ccoeff', 'template_sqdiff', 'features')
NO_RANGE = None


@dataclass(frozen=True)
class Spec:
    name: str
    default: object
    description: str
    range: tuple | None = NO_RANGE    # inclusive (lo, hi) for numbers
    live: bool = False                # applied to the next request when set


SPECS = [
    Spec('autostart', True, 'configure and activate on start (false: a lifecycle manager does)'),
    Spec('map_yaml', '', 'nav2 map YAML to localize in (empty: the shipped map)'),
    Spec('use_map_topic', False, 'take the map from an OccupancyGrid topic instead of map_yaml'),
    Spec('map_topic', '/map', 'OccupancyGrid topic (transient local, like nav2 map_server)'),
    Spec('maps', [], 'a map set (floors, sites): map YAMLs, PATH or NAME=PATH (named by the file without .yaml), '
                     'each searched on every goal, the answer naming its map; empty: map_yaml alone'),
    Spec('served_map', '', 'in a map set, the map nav2 map_server serves on /map (empty: the first of maps); '
                           '/initialpose is published only for an answer on it (set it when map_server switches)',
         live=True),
    Spec('stored_pose_file', '', 'start-up from the last pose: a file that keeps the last confident pose published '
                                 '(with its map and the odometry then), tried first at activation and on '
                                 '~/localize_from_stored_pose - confirmed by the scan or a full search; empty: off'),
    Spec('stored_pose_max_age_s', 0.0, 'a stored pose older than this is not tried (0: any age), s', (0.0, 1e9),
         live=True),
    Spec('scan_topics', ['/scan'], 'sensor_msgs/LaserScan topics merged into one view (the first: the primary '
                                   'laser, which the health watch and resolve-by-motion use)'),
    Spec('scan_topic', '', 'the one-laser alias of scan_topics (set: scan_topics is [scan_topic])'),
    Spec('cloud_topics', [], 'sensor_msgs/PointCloud2 topics (3D lidars) merged into the view'),
    Spec('merge_window_s', _V.merge_window_s, "a sensor whose newest message arrived longer before the newest "
                                              "sensor's is left out of the view, s", (0.0, 10.0), live=True),
    Spec('max_clock_offset_s', _V.max_clock_offset_s, "a sensor whose stamps are this far off the others' for "
                                                      "messages that arrived together is left out, s",
         (0.0, 3600.0), live=True),
    Spec('cloud_z_min', _V.cloud_z_min, 'clouds (and tilted lasers): points lower above the floor, in the base '
                                        'frame, are left out (the floor), m', (-100.0, 100.0), live=True),
    Spec('cloud_z_max', _V.cloud_z_max, 'clouds (and tilted lasers): points higher are left out (the ceiling), m',
         (-100.0, 100.0), live=True),
    Spec('voxel_size', _V.voxel_size, "a merged view keeps one point per cell of this size (0: all), m",
         (0.0, 10.0), live=True),
    Spec('initialpose_topic', '/initialpose', 'where confident poses are published (reliable, volatile as AMCL '
                                              'subscribes it)'),
    Spec('scan_timeout_s', 5.0, 'how long a request waits for a scan that arrives after it, s',
         BOUNDS['scan_timeout_s'], live=True),
    Spec('map_frame', 'map', 'frame of the published pose'),
    Spec('base_frame', 'base_link', 'robot base frame (sensor mountings are looked up on it in tf)'),
    Spec('pose_topic', '/amcl_pose', "the localizer's pose (PoseWithCovarianceStamped, in map_frame), watched"),
    Spec('odom_topic', '/odom', 'nav_msgs/Odometry: moves the watched pose and the hypotheses'),
    Spec('cmd_vel_topic', '/cmd_vel', 'where rotate_in_place turns the robot (Twist)'),
    Spec('rotate_speed', 0.4, 'rotate_in_place turn rate, rad/s', (0.05, 2.0), live=True),
    Spec('health.period_s', 0.5, 'how often the fit at the watched pose is checked, s', (0.05, 60.0)),
    Spec('relocalize.resolve_by_motion_s', 0.0, 'automatic relocalization: how long an ambiguous answer may be '
                                                'followed while the robot moves (0: not), s',
         BOUNDS['resolve_by_motion_s'], live=True),
    Spec('auto_relocalize', _S.auto_relocalize, 'relocalize on its own at start (no pose yet) and when lost; '
                                                'publishes poses', live=True),
    Spec('health.degraded_fit', _S.degraded_fit, 'fit below which the state is degraded', (0.0, 1.0), live=True),
    Spec('health.lost_fit', _S.lost_fit, 'fit below which, for health.lost_after_s, it is lost', (0.0, 1.0),
         live=True),
    Spec('health.lost_after_s', _S.lost_after_s, 'how long the fit must stay low to be lost, s', (0.0, 3600.0),
         live=True),
    Spec('relocalize.start_delay_s', _S.start_delay_s, 'with no pose ever received: wait this long after '
                                                       'activation, s', (0.0, 3600.0), live=True),
    Spec('relocalize.min_interval_s', _S.min_interval_s, 'between two relocalizations, s', (0.0, 3600.0), live=True),
    Spec('relocalize.max_attempts', _S.max_attempts, 'relocalizations in a row without recovering, then stay lost',
         (1, 1000), live=True),
    Spec('relocalize.settle_s', _S.settle_s, 'after publishing, how long the localizer has to take the pose '
                                             'before it is retried, s', (0.1, 3600.0), live=True),
    Spec('method', _L.method, f'default matcher: {", ".join(method_names())}; one of the prepared methods (bnb, '
                              f'`methods` and the method configured)', live=True),
    Spec('methods', list(PREPARED_METHODS), 'matchers precomputed with each map, at configure or when a map '
                                            'arrives, besides bnb and `method`; a goal may name only a prepared '
                                            'one (one whose precomputation would exceed its memory budget on the '
                                            'map is refused with the reason)'),
    Spec('angle_step_deg', _L.angle_step_deg, 'rotation step of the template matcher, degrees', limits.ANGLE_STEP_DEG,
         live=True),
    Spec('opening_kernel', _L.closing_kernel, 'kernel of the morphological closing of the local map\'s obstacles '
                                              '(the thesis\'s "opening" of its free space), pixels (0 = off)',
         (0, 31), live=True),
    Spec('covariance_xy', _L.covariance_xy, 'x and y variance published with the thesis matchers, m^2',
         (1e-6, 100.0), live=True),
    Spec('covariance_yaw', _L.covariance_yaw, 'yaw variance published with the thesis matchers, rad^2',
         (1e-6, 10.0), live=True),
    Spec('laser_x', 0.0, 'laser position on the base, m (used when tf has none)', limits.LASER_OFFSET_M, live=True),
    Spec('laser_y', 0.0, 'laser position on the base, m (used when tf has none)', limits.LASER_OFFSET_M, live=True),
    Spec('laser_yaw', 0.0, 'laser heading on the base, rad (used when tf has none)', limits.LASER_ANGLE_RAD, live=True),
    Spec('laser_roll', 0.0, f'laser roll on the base, rad (used when tf has none): pi for a laser mounted upside down; '
                            f'a tilted laser (more than {limits.MAX_LASER_TILT_DEG:g} deg from 0 or pi) is refused',
         limits.LASER_ANGLE_RAD, live=True),
    Spec('max_search_s', 5.0, 'seconds a goal\'s search may take, shared by every map it searches; then the goal ends '
                              '"search incomplete" with what was explored (a goal always ends)',
         limits.MAX_SEARCH_S, live=True),
] + [Spec(f'bnb.{name}', default, f'bnb matcher: {help_text} (applied on configure: a new precomputation)',
          option_range(name)) for name, _, default, help_text in option_fields()]
BY_NAME = {s.name: s for s in SPECS}


class ConfigError(ParameterError):
    """A parameter value the server cannot run with; the message names it."""


@dataclass(frozen=True)
class ServerConfig:
    values: dict                      # parameter name -> value, every parameter
    localizer: LocalizerConfig
    supervisor: SupervisorConfig
    view: ViewConfig = ViewConfig()
    sensors: tuple = ()              # SensorSpec per configured sensor (topics, mountings from parameters)
    prepared: tuple = ()             # canonical matcher names precomputed with each map (read at configure)

    def __getitem__(self, name: str):
        return self.values[name]

    @property
    def map_yaml(self) -> str:
        return self.values['map_yaml'] or default_map_yaml()

    @property
    def map_files(self) -> dict[str, str]:
        """The maps to serve, by name: `maps` (checked by build_config), or map_yaml alone."""
        return map_files(self.values['maps']) if self.values['maps'] else {map_name(self.map_yaml): self.map_yaml}

    @property
    def served_map(self) -> str:
        return self.values['served_map'] or next(iter(self.map_files))

    def request_defaults(self) -> RequestDefaults:
        v = self.values
        return RequestDefaults(v['method'], v['angle_step_deg'], v['scan_timeout_s'])


def map_files(entries: list) -> dict[str, str]:
    """`maps` entries (PATH or NAME=PATH, core.map_set.named_paths) by name."""
    try:
        return named_paths(entries)
    except MapSetError as e:
        raise ConfigError(f'parameter maps: {e}') from None


def check_map_set(v: dict) -> None:
    if v['maps'] and v['use_map_topic']:
        raise ConfigError('parameter maps: a map set is read from files; use_map_topic takes one map from a topic '
                          '(set one of them)')
    names = map_files(v['maps']) if v['maps'] else {}
    if v['served_map'] and v['served_map'] not in names:
        raise ConfigError(f'parameter served_map: {v["served_map"]} is not a map of the set (maps: '
                          f'{", ".join(names) or "none"})')


def build_config(values: dict, mounts: dict | None = None) -> ServerConfig:
    """The snapshot of `values`; ConfigError naming the first value it cannot run with."""
    try:       # an integer for a double is that double (param_types); a value of another kind is refused
        values = {name: typed_value(name, BY_NAME[name].default, value, BY_NAME[name].range)
                  for name, value in values.items()}
    except ParameterError as e:
        raise ConfigError(str(e)) from None
    v = values
    check_map_set(v)
    try:
        LaserMount.from_mount3d(Mount3D(v['laser_x'], v['laser_y'], 0.0, v['laser_roll'], 0.0, v['laser_yaw']))
    except MountError as e:
        raise ConfigError(f'parameter laser_roll: {e}') from None
    try:
        prepared = tuple(dict.fromkeys(resolve_method(m) for m in (v['method'], TRACKER_METHOD, *v['methods'])))
    except ValueError as e:
        raise ConfigError(f'parameter method or methods: {e}') from None
    try:
        bnb = BranchAndBoundOptions(**{name: v[f'bnb.{name}'] for name, *_ in option_fields()})
    except ValueError as e:
        raise ConfigError(f'parameter {"method" if "method" in str(e) else "bnb.*"}: {e}') from None
    localizer = LocalizerConfig(method=v['method'], angle_step_deg=v['angle_step_deg'],
                                closing_kernel=v['opening_kernel'], covariance_xy=v['covariance_xy'],
                                covariance_yaw=v['covariance_yaw'],
                                base_T_laser=Rigid2D(v['laser_x'], v['laser_y'], v['laser_yaw']),
                                max_search_s=v['max_search_s'], bnb=bnb)
    supervisor = SupervisorConfig(auto_relocalize=v['auto_relocalize'], degraded_fit=v['health.degraded_fit'],
                                  lost_fit=v['health.lost_fit'], lost_after_s=v['health.lost_after_s'],
                                  start_delay_s=v['relocalize.start_delay_s'],
                                  min_interval_s=v['relocalize.min_interval_s'],
                                  max_attempts=v['relocalize.max_attempts'], settle_s=v['relocalize.settle_s'])
    try:
        view = ViewConfig(merge_window_s=v['merge_window_s'], max_clock_offset_s=v['max_clock_offset_s'],
                          cloud_z_min=v['cloud_z_min'], cloud_z_max=v['cloud_z_max'], voxel_size=v['voxel_size'])
        sensors = sensor_specs(v['scan_topics'], v['scan_topic'], v['cloud_topics'], mounts or {})
    except ValueError as e:
        raise ConfigError(f'parameter {e}') from None
    return ServerConfig(dict(values), localizer, supervisor, view, sensors, prepared)


def _descriptor(spec: Spec) -> ParameterDescriptor:
    when = 'live' if spec.live else 'applied on configure'
    return describe(spec.default, f'{spec.description} [{when}]', spec.range)


def declare_parameters(node) -> dict[str, str]:
    """Declare every parameter on `node`; returns the problems with the values it was
    started with, by name (an out-of-range override is declared with its default and
    reported, so configure fails with the reason instead of the constructor raising)."""
    problems = {}
    for spec in SPECS:
        # an empty list says no type: declared as a string array without a value (read as [])
        default = Parameter.Type.STRING_ARRAY if spec.default == [] else spec.default
        problem = declare(node, spec.name, default, _descriptor(spec))
        if problem:
            problems[spec.name] = problem
    return problems


def parameter_value(node, name: str):
    """A declared parameter's value ([] for a list declared without one)."""
    try:
        return node.get_parameter(name).value
    except ParameterUninitializedException:
        return []


def read_config(node) -> ServerConfig:
    """All parameters as they are now (on_configure), each sensor's `sensors.<name>.mount`
    declared when first configured; ConfigError when one is unusable."""
    values = {spec.name: parameter_value(node, spec.name) for spec in SPECS}
    mounts = {}
    try:
        specs = sensor_specs(values['scan_topics'], values['scan_topic'], values['cloud_topics'], {})
    except ValueError as e:
        raise ConfigError(f'parameter {e}') from None
    for sensor in specs:
        if not node.has_parameter(sensor.mount_parameter):
            descriptor = ParameterDescriptor(description=f'{sensor.topic} on the base (x y z roll pitch yaw; m, '
                                                         f'rad) when tf has none [applied on configure]')
            problem = declare(node, sensor.mount_parameter, Parameter.Type.DOUBLE_ARRAY, descriptor)
            if problem:     # the value it was started with; set it and configure
                raise ConfigError(problem)
        mounts[sensor.topic] = parameter_value(node, sensor.mount_parameter) or None
    return build_config(values, mounts)


def check_set(current: dict, params, configured: tuple = ()) -> SetParametersResult:
    """The set-parameters callback's answer: a value the server cannot run with is refused
    with the reason; so is, while configured, one that is read only at configure (the
    reason says how to apply it: rclpy passes on no reason of a successful set, so a
    stored-for-later value could not say so); a live one is accepted (`apply_live`).
    `configured`: the methods prepared at configure (empty: not configured) - a live
    `method` must be one of them."""
    values = dict(current)
    for p in params:
        if p.name.startswith('sensors.') and p.value is not None:     # None: declared without a value
            problem = ('read at configure, not live - deactivate and clean up the node, set it, configure again'
                       if configured else check_mount_value(p.value))
            if problem:
                return SetParametersResult(successful=False, reason=f'{p.name}: {problem}')
        if p.name not in BY_NAME:
            continue
        if configured and not BY_NAME[p.name].live:
            return SetParametersResult(successful=False, reason=(
                f'{p.name}: read at configure, not live - deactivate and clean up the node, set it, configure '
                f'again'))
        values[p.name] = p.value
    if not any(p.name in BY_NAME for p in params):    # only mountings: the others' values are not at stake
        return SetParametersResult(successful=True)
    try:
        fresh = build_config(values)
    except ConfigError as e:
        return SetParametersResult(successful=False, reason=str(e))
    if configured and fresh.prepared[0] not in configured:
        return SetParametersResult(successful=False, reason=(
            f'method: {values["method"]} is not prepared (prepared: {", ".join(configured)}); add it to methods: '
            f'deactivate and clean up the node, set both, configure again'))
    return SetParametersResult(successful=True)


def apply_live(active: ServerConfig, params) -> ServerConfig:
    """`active` with the live ones of `params` applied (the others wait for configure)."""
    live = {p.name: p.value for p in params if p.name in BY_NAME and BY_NAME[p.name].live}
    if not live:
        return active
    fresh = build_config({**active.values, **live}, {s.topic: s.mount for s in active.sensors})
    return replace(fresh, localizer=replace(fresh.localizer, bnb=active.localizer.bnb), prepared=active.prepared)
