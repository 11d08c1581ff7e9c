"""`ros2 run global_loc server`: the global-localization action server.

Action `localize` (global_loc_interfaces/action/Localize): on a goal, take the next scan
that arrives on `scan_topic` after the goal, localize it in the map, stream feedback,
and publish the pose on `initialpose_topic` (PoseWithCovarianceStamped, frame `map`)
when the result is successful and the goal asks for it, so AMCL re-initializes.

One goal at a time: a goal that arrives while another runs is accepted and immediately
aborted with the message "busy: ..." (an action rejection cannot carry a reason, and a
client deserves one). Every failure — no map, bad method, no scan in time, unusable
scan, internal error — aborts that goal with a message; the node keeps serving.
"""
from __future__ import annotations

import math
import sys
import threading
import time
import traceback

import rclpy
from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped
from global_loc_interfaces.action import Localize
from nav_msgs.msg import OccupancyGrid
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import LaserScan

from .localizer import Localizer, LocalizerConfig
from .map_io import MapError, load_map_yaml
from .matchers import Cancelled, MethodError, method_names, resolve_method
from .node_main import run_node
from .ros_convert import map_from_msg, pose_to_msg, pose_with_covariance, scan_from_msg
from .scan import ScanError
from .transform import Rigid2D


def default_map_yaml() -> str:
    """The shipped map from the package's share directory (ament index)."""
    try:
        from ament_index_python.packages import get_package_share_directory
        return f'{get_package_share_directory("global_loc")}/maps/office.yaml'
    except Exception:   # not installed through colcon: the source checkout
        from .paths import default_map_yaml as source_default
        return source_default()


class GlobalLocServer(Node):
    def __init__(self):
        super().__init__('global_loc_server')
        defaults = LocalizerConfig()

        def param(name, value, description, **ranges):
            return self.declare_parameter(name, value, ParameterDescriptor(description=description, **ranges)).value

        fr = lambda lo, hi: [FloatingPointRange(from_value=lo, to_value=hi)]  # noqa: E731
        self.map_yaml = param('map_yaml', default_map_yaml(), 'nav2 map YAML to localize in (default: the shipped office map)')
        self.use_map_topic = param('use_map_topic', False, 'take the map from an OccupancyGrid topic instead of map_yaml')
        self.map_topic = param('map_topic', '/map', 'OccupancyGrid topic (transient local, like nav2 map_server)')
        self.scan_topic = param('scan_topic', '/scan', 'sensor_msgs/LaserScan topic')
        self.initialpose_topic = param('initialpose_topic', '/initialpose', 'where successful poses are published')
        self.method = param('method', defaults.method, f'default matcher: {", ".join(method_names())}')
        angle_step = param('angle_step_deg', defaults.angle_step_deg, 'rotation step of the template matcher, degrees',
                           floating_point_range=fr(0.1, 180.0))
        opening = param('opening_kernel', defaults.opening_kernel, 'opening kernel of the local map, pixels (0 = off)',
                        integer_range=[IntegerRange(from_value=0, to_value=31, step=1)])
        cov_xy = param('covariance_xy', defaults.covariance_xy, 'published x and y variance, m^2',
                       floating_point_range=fr(1e-6, 100.0))
        cov_yaw = param('covariance_yaw', defaults.covariance_yaw, 'published yaw variance, rad^2',
                        floating_point_range=fr(1e-6, 10.0))
        self.scan_timeout = param('scan_timeout_s', 5.0, 'how long a goal waits for a fresh scan, s',
                                  floating_point_range=fr(0.1, 600.0))
        self.map_frame = param('map_frame', 'map', 'frame of the published pose')
        self.base_frame = param('base_frame', 'base_link', 'robot base frame (for tf2, when available)')
        laser = Rigid2D(param('laser_x', 0.0, 'laser position on the base, m (used without tf2)'),
                        param('laser_y', 0.0, 'laser position on the base, m (used without tf2)'),
                        param('laser_yaw', 0.0, 'laser heading on the base, rad (used without tf2)'))
        self.config = LocalizerConfig(method=self.method, angle_step_deg=angle_step, opening_kernel=opening,
                                      covariance_xy=cov_xy, covariance_yaw=cov_yaw, base_T_laser=laser)

        self.group = ReentrantCallbackGroup()
        self.localizer: Localizer | None = None
        self.map_error = 'no map loaded yet'
        self.busy = threading.Lock()
        self.scan_cond = threading.Condition()
        self.latest_scan: tuple[float, LaserScan] | None = None   # (monotonic receive time, msg)
        self.tf_buffer = self._make_tf_buffer()

        self.create_subscription(LaserScan, self.scan_topic, self.on_scan, qos_profile_sensor_data,
                                 callback_group=self.group)
        self.initialpose_pub = self.create_publisher(
            PoseWithCovarianceStamped, self.initialpose_topic,
            QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
        if self.use_map_topic:
            self.create_subscription(OccupancyGrid, self.map_topic, self.on_map,
                                     QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                                durability=DurabilityPolicy.TRANSIENT_LOCAL),
                                     callback_group=self.group)
            self.map_error = f'waiting for a map on {self.map_topic}'
            self.get_logger().info(f'waiting for the map on {self.map_topic}')
        else:
            self.load_map_file(self.map_yaml)
        self.action_server = ActionServer(self, Localize, 'localize', self.execute, callback_group=self.group,
                                          goal_callback=self.on_goal, cancel_callback=self.on_cancel)
        self.get_logger().info(f'ready: action "localize", scans on {self.scan_topic}, '
                               f'poses to {self.initialpose_topic}, default method {self.method}')

    # ---- map -----------------------------------------------------------------
    def load_map_file(self, path: str) -> None:
        try:
            self.set_map(load_map_yaml(path))
        except MapError as e:
            self.map_error = f'map not loaded: {e}'
            self.get_logger().error(f'{self.map_error}; goals will be aborted until a map is available')

    def set_map(self, occupancy_map) -> None:
        localizer = Localizer(occupancy_map, self.config)
        try:
            t0 = time.perf_counter()
            localizer.matcher(self.method)   # precompute the default matcher now, not in the first goal
            self.get_logger().info(f'map {occupancy_map.source}: {occupancy_map.width} x {occupancy_map.height} '
                                   f'cells at {occupancy_map.resolution} m; {self.method} ready in '
                                   f'{time.perf_counter() - t0:.2f} s')
        except MethodError as e:
            self.get_logger().error(f'default method: {e}')
        self.localizer = localizer

    def on_map(self, msg: OccupancyGrid) -> None:
        """A new map from the map topic replaces the current one (goals in flight keep theirs)."""
        try:
            self.set_map(map_from_msg(msg))
        except MapError as e:
            self.map_error = f'map not loaded: {e}'
            self.get_logger().error(self.map_error)

    # ---- scans ---------------------------------------------------------------
    def on_scan(self, msg: LaserScan) -> None:
        """Keep only the newest scan, with its arrival time."""
        with self.scan_cond:
            self.latest_scan = (time.monotonic(), msg)
            self.scan_cond.notify_all()

    def wait_for_fresh_scan(self, goal_handle, since: float, timeout: float):
        """The first scan received after `since`; None on timeout; raises Cancelled."""
        deadline = since + timeout
        with self.scan_cond:
            while True:
                if self.latest_scan is not None and self.latest_scan[0] >= since:
                    return self.latest_scan[1]
                if goal_handle.is_cancel_requested:
                    raise Cancelled()
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self.scan_cond.wait(min(remaining, 0.05))

    def _make_tf_buffer(self):
        try:
            import tf2_ros
        except ImportError:
            self.get_logger().info('tf2_ros not available: the laser mounting comes from laser_x/laser_y/laser_yaw')
            return None
        buffer = tf2_ros.Buffer()
        self._tf_listener = tf2_ros.TransformListener(buffer, self)
        return buffer

    def base_T_laser(self, laser_frame: str) -> Rigid2D:
        """The laser's mounting on the base: from tf2 when it has it, else the parameters."""
        if self.tf_buffer is not None and laser_frame:
            try:
                from .ros_convert import quaternion_to_yaw
                t = self.tf_buffer.lookup_transform(self.base_frame, laser_frame, rclpy.time.Time()).transform
                return Rigid2D(t.translation.x, t.translation.y, quaternion_to_yaw(t.rotation))
            except Exception as e:   # tf2 raises several types; any means "not known"
                self.get_logger().warn(f'no tf {self.base_frame} <- {laser_frame} ({e}); using the laser_* parameters')
        return self.config.base_T_laser

    # ---- action ----------------------------------------------------------------
    def on_goal(self, goal_request) -> GoalResponse:
        """Accept every goal; execute() aborts it with a reason if it cannot run."""
        return GoalResponse.ACCEPT

    def on_cancel(self, goal_handle) -> CancelResponse:
        """Accept every cancel; the search stops at its next progress report."""
        self.get_logger().info('cancel requested')
        return CancelResponse.ACCEPT

    def execute(self, goal_handle):
        """Run one localization; always ends the goal (succeed, abort or canceled)."""
        if not self.busy.acquire(blocking=False):
            self.get_logger().warn('goal aborted: busy with another goal')
            return self.finish(goal_handle, 'abort', 'busy: another goal is running (one at a time); retry when it ends')
        try:
            return self.run_goal(goal_handle)
        except Cancelled:
            self.get_logger().info('goal canceled')
            return self.finish(goal_handle, 'cancel', 'canceled')
        except Exception as e:   # an internal error must end this goal, not the node
            self.get_logger().error(f'internal error: {e}\n{traceback.format_exc()}')
            return self.finish(goal_handle, 'abort', f'internal error: {type(e).__name__}: {e}')
        finally:
            self.busy.release()

    def run_goal(self, goal_handle):
        goal = goal_handle.request
        start = time.monotonic()
        localizer = self.localizer
        if localizer is None:
            return self.finish(goal_handle, 'abort', self.map_error)
        method = goal.method or self.method
        try:
            resolve_method(method)
        except MethodError as e:
            return self.finish(goal_handle, 'abort', str(e))
        if not (0 <= goal.angle_step_deg <= 180) or not math.isfinite(goal.angle_step_deg):
            return self.finish(goal_handle, 'abort', f'angle_step_deg must be in [0, 180], got {goal.angle_step_deg}')
        timeout = goal.timeout_s if goal.timeout_s > 0 else self.scan_timeout
        self.get_logger().info(f'goal: method {method}, waiting up to {timeout:.1f} s for a scan on {self.scan_topic}')
        self.feedback(goal_handle, 0.0, 'waiting_for_scan', 0.0)
        msg = self.wait_for_fresh_scan(goal_handle, start, timeout)
        if msg is None:
            return self.finish(goal_handle, 'abort', f'no scan on {self.scan_topic} within {timeout:.1f} s')
        self.feedback(goal_handle, 0.05, 'preparing_scan', 0.0)   # local map or points, per method
        self.get_logger().info(f'matching a scan of {len(msg.ranges)} beams')
        base_T_laser = self.base_T_laser(msg.header.frame_id)
        last = [0.0]

        def progress(fraction, best):
            if goal_handle.is_cancel_requested:
                raise Cancelled()
            now = time.monotonic()
            if now - last[0] > 0.1 or fraction >= 1.0:   # at most ~10 feedback messages a second
                last[0] = now
                self.feedback(goal_handle, 0.05 + 0.9 * fraction, 'matching', best)

        try:
            result = localizer.localize(scan_from_msg(msg), method=method,
                                        angle_step_deg=goal.angle_step_deg or None, progress=progress,
                                        base_T_laser=base_T_laser)
        except ScanError as e:
            return self.finish(goal_handle, 'abort', f'scan unusable: {e}')
        out = Localize.Result(success=result.success, message=result.message, score=float(result.score),
                              confidence=float(result.confidence), elapsed_s=time.monotonic() - start)
        out.hypotheses = PoseArray()
        out.hypotheses.header.frame_id = self.map_frame
        out.hypotheses.header.stamp = msg.header.stamp
        out.hypotheses.poses = [pose_to_msg(h.pose) for h in result.hypotheses]
        out.hypothesis_scores = [float(h.score) for h in result.hypotheses]
        if result.pose is not None:
            out.pose = pose_with_covariance(result.pose, result.covariance, self.map_frame, msg.header.stamp)
        p = result.pose
        summary = (f'{result.message}: x={p.x:.3f} y={p.y:.3f} yaw={math.degrees(p.yaw):.1f} deg, '
                   f'score {result.score:.3f}, {result.time_s:.2f} s') if p else result.message
        if result.pose is not None and goal.publish_initialpose and (result.success or goal.publish_if_ambiguous):
            self.initialpose_pub.publish(out.pose)
            summary += f'; published on {self.initialpose_topic}'
        self.get_logger().info(summary)
        return self.finish(goal_handle, 'succeed' if result.success else 'abort', result.message, out)

    def feedback(self, goal_handle, progress: float, stage: str, best: float) -> None:
        goal_handle.publish_feedback(Localize.Feedback(progress=float(progress), stage=stage,
                                                       best_score=float(best) if math.isfinite(best) else 0.0))

    def finish(self, goal_handle, how: str, message: str, result=None):
        result = result or Localize.Result(success=False)
        result.message = message
        if how == 'succeed':
            goal_handle.succeed()
        elif how == 'cancel':
            goal_handle.canceled()
        else:
            self.get_logger().warn(f'goal aborted: {message}')
            goal_handle.abort()
        return result


def main(args=None):
    # Four threads: a running goal never starves the scan, cancel and goal callbacks.
    sys.exit(run_node(GlobalLocServer, lambda: MultiThreadedExecutor(num_threads=4), args=args))


if __name__ == '__main__':
    main()
