"""`ros2 run global_loc server`: the global-localization action server.

Action `localize` (global_loc_interfaces/action/Localize): on a goal, take the next scan
that arrives on `scan_topic` after the goal, localize it in the map, stream feedback,
and publish the pose on `initialpose_topic` (PoseWithCovarianceStamped, frame `map`)
when the result is successful and the goal asks for it, so AMCL re-initializes.

One goal at a time: a goal that arrives while another runs is accepted and at once
aborted with outcome BUSY (an action rejection cannot carry a reason). Every failure
ends that goal with its outcome and a message; the node keeps serving.
"""
from __future__ import annotations

import math
import sys
import threading
import time
import traceback

import rclpy
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import OccupancyGrid
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import LaserScan

from global_loc_interfaces.action import Localize

from ..core.localizer import Localizer, check_angle_step
from ..core.map_io import MapError, load_map_yaml
from ..core.matchers import MethodError, resolve_method
from ..core.outcome import Cancelled, Outcome
from ..core.scan import ScanError
from ..core.scan_waiter import ScanWaiter
from ..core.transform import Rigid2D, format_pose
from .convert import ended_result, map_from_msg, quaternion_to_yaw, result_to_msg, scan_from_msg
from .node_main import run_node
from .parameters import declare_server_parameters


class GlobalLocServer(Node):
    def __init__(self):
        super().__init__('global_loc_server')
        self.settings, self.config = declare_server_parameters(self)
        s = self.settings
        self.group = ReentrantCallbackGroup()
        self.localizer: Localizer | None = None
        self.map_error = 'no map loaded yet'
        self.busy = threading.Lock()
        self.scans: ScanWaiter[LaserScan] = ScanWaiter()
        self.tf_buffer = self._make_tf_buffer()

        self.create_subscription(LaserScan, s.scan_topic, self.scans.put, qos_profile_sensor_data,
                                 callback_group=self.group)
        self.initialpose_pub = self.create_publisher(PoseWithCovarianceStamped, s.initialpose_topic,
                                                     QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
        if s.use_map_topic:
            self.create_subscription(OccupancyGrid, s.map_topic, self.on_map,
                                     QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                                durability=DurabilityPolicy.TRANSIENT_LOCAL),
                                     callback_group=self.group)
            self.map_error = f'waiting for a map on {s.map_topic}'
            self.get_logger().info(f'waiting for the map on {s.map_topic}')
        else:
            self.load_map_file(s.map_yaml)
        self.action_server = ActionServer(self, Localize, 'localize', self.execute, callback_group=self.group,
                                          goal_callback=self.on_goal, cancel_callback=self.on_cancel)
        self.get_logger().info(f'ready: action "localize", scans on {s.scan_topic}, '
                               f'poses to {s.initialpose_topic}, default method {self.config.method}')

    # ---- map -----------------------------------------------------------------
    def load_map_file(self, path: str) -> None:
        try:
            self.set_map(load_map_yaml(path))
        except MapError as e:
            self.map_error = f'map not loaded: {e}'
            self.get_logger().error(f'{self.map_error}; goals will be aborted until a map is available')

    def set_map(self, occupancy_map) -> None:
        """Use `occupancy_map` from now on, with the default matcher precomputed now, not in the first goal."""
        localizer = Localizer(occupancy_map, self.config)
        try:
            t0 = time.perf_counter()
            localizer.matcher(self.config.method)
            self.get_logger().info(f'map {occupancy_map.source}: {occupancy_map.width} x {occupancy_map.height} '
                                   f'cells at {occupancy_map.resolution} m; {self.config.method} ready in '
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

    # ---- laser mounting --------------------------------------------------------
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
        base = self.settings.base_frame
        if self.tf_buffer is not None and laser_frame:
            try:
                t = self.tf_buffer.lookup_transform(base, laser_frame, rclpy.time.Time()).transform
                return Rigid2D(t.translation.x, t.translation.y, quaternion_to_yaw(t.rotation))
            except Exception as e:   # tf2 raises several types; any means "not known"
                self.get_logger().warn(f'no tf {base} <- {laser_frame} ({e}); using the laser_* parameters')
        return self.config.base_T_laser

    # ---- action ----------------------------------------------------------------
    def on_goal(self, goal_request) -> GoalResponse:
        """Accept every goal; execute() ends it with an outcome if it cannot run."""
        return GoalResponse.ACCEPT

    def on_cancel(self, goal_handle) -> CancelResponse:
        """Accept every cancel; the search stops at its next progress report."""
        self.get_logger().info('cancel requested')
        return CancelResponse.ACCEPT

    def execute(self, goal_handle):
        """Run one localization; always ends the goal (succeed, abort or canceled)."""
        if not self.busy.acquire(blocking=False):
            return self.finish(goal_handle, ended_result(
                Outcome.BUSY, 'busy: another goal is running (one at a time); retry when it ends'))
        try:
            return self.run_goal(goal_handle)
        except Cancelled:
            return self.finish(goal_handle, ended_result(Outcome.CANCELED, 'canceled'))
        except Exception as e:   # an internal error must end this goal, not the node
            self.get_logger().error(f'internal error: {e}\n{traceback.format_exc()}')
            return self.finish(goal_handle, ended_result(Outcome.INTERNAL_ERROR,
                                                         f'internal error: {type(e).__name__}: {e}'))
        finally:
            self.busy.release()

    def run_goal(self, goal_handle):
        goal = goal_handle.request
        start = time.monotonic()
        localizer = self.localizer
        if localizer is None:
            return self.finish(goal_handle, ended_result(Outcome.NO_MAP, self.map_error))
        method = goal.method or self.config.method
        try:
            resolve_method(method)
            check_angle_step(goal.angle_step_deg or self.config.angle_step_deg)
        except ValueError as e:    # MethodError is one
            return self.finish(goal_handle, ended_result(Outcome.BAD_GOAL, str(e)))
        timeout = goal.timeout_s if goal.timeout_s > 0 else self.settings.scan_timeout_s
        topic = self.settings.scan_topic
        self.get_logger().info(f'goal: method {method}, waiting up to {timeout:.1f} s for a scan on {topic}')
        self.feedback(goal_handle, 0.0, 'waiting_for_scan', 0.0)
        msg = self.scans.wait_after(start, timeout, lambda: goal_handle.is_cancel_requested)
        if msg is None:
            return self.finish(goal_handle, ended_result(Outcome.NO_SCAN, f'no scan on {topic} within {timeout:.1f} s'))
        self.feedback(goal_handle, 0.05, 'preparing_scan', 0.0)   # local map or points, per method
        self.get_logger().info(f'matching a scan of {len(msg.ranges)} beams')
        try:
            result = localizer.localize(scan_from_msg(msg), method=method, angle_step_deg=goal.angle_step_deg or None,
                                        progress=self.progress_reporter(goal_handle),
                                        base_T_laser=self.base_T_laser(msg.header.frame_id))
        except ScanError as e:
            return self.finish(goal_handle, ended_result(Outcome.UNUSABLE_SCAN, f'scan unusable: {e}'))
        out = result_to_msg(result, self.settings.map_frame, msg.header.stamp, time.monotonic() - start)
        summary = result.message
        if result.pose is not None:
            summary += f': {format_pose(result.pose)}, score {result.score:.3f}, {result.time_s:.2f} s'
            if goal.publish_initialpose and (result.success or goal.publish_if_ambiguous):
                self.initialpose_pub.publish(out.pose)
                summary += f'; published on {self.settings.initialpose_topic}'
        self.get_logger().info(summary)
        return self.finish(goal_handle, out)

    def progress_reporter(self, goal_handle):
        """The matcher's progress callback: raises Cancelled on a cancel request, sends
        at most ~10 feedback messages a second."""
        last = [0.0]

        def progress(fraction, best):
            if goal_handle.is_cancel_requested:
                raise Cancelled()
            now = time.monotonic()
            if now - last[0] > 0.1 or fraction >= 1.0:
                last[0] = now
                self.feedback(goal_handle, 0.05 + 0.9 * fraction, 'matching', best)
        return progress

    def feedback(self, goal_handle, progress: float, stage: str, best: float) -> None:
        goal_handle.publish_feedback(Localize.Feedback(progress=float(progress), stage=stage,
                                                       best_score=float(best) if math.isfinite(best) else 0.0))

    def finish(self, goal_handle, result):
        """End the goal as its outcome says, logging why when it did not succeed."""
        if result.outcome == Outcome.LOCALIZED:
            goal_handle.succeed()
        elif result.outcome == Outcome.CANCELED:
            self.get_logger().info('goal canceled')
            goal_handle.canceled()
        else:
            self.get_logger().warn(f'goal aborted: {result.message}')
            goal_handle.abort()
        return result


def main(args=None):
    # Four threads: a running goal never starves the scan, cancel and goal callbacks.
    sys.exit(run_node(GlobalLocServer, lambda: MultiThreadedExecutor(num_threads=4), args=args))


if __name__ == '__main__':
    main()
