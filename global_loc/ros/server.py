"""`ros2 run global_loc server`: the global-localization server, a lifecycle node.

States as in nav2: *configure* loads the map (file or topic) and precomputes the default
matcher; *activate* serves; *deactivate* stops accepting work (a running localization
ends canceled); *cleanup* drops the map. With `autostart` (default) it configures and
activates itself; otherwise a lifecycle manager drives it (`~/change_state`).

Three ways to ask, one code path (`serve`), one localization at a time:
- action `localize` (global_loc_interfaces/action/Localize): feedback, the result with
  its typed outcome, an optional search prior;
- `~/trigger` (std_srvs/Trigger): the server's defaults, `success` and a one-line message;
- `~/reinitialize_global_localization` (std_srvs/Empty): the same, for nav2's
  ReinitializeGlobalLocalization behaviour-tree node.
Each takes the first scan that arrives after the request, localizes it, publishes the
pose on `initialpose_topic` when confident, and shows the hypotheses and the local map
on `~/hypotheses`, `~/hypothesis_markers`, `~/local_map` (RViz; transient local). Asked
while not active, busy, or unable, it answers with the outcome and a reason. An ambiguous
answer can be settled by motion (goal `resolve_by_motion_s`, ros/motion.py); the robot's
health is watched, and with `auto_relocalize` restored without a request (ros/watch.py).
"""
from __future__ import annotations

import contextlib
import math
import threading
import time
import traceback

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped, Twist
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.time import Time
from sensor_msgs.msg import LaserScan
from std_msgs.msg import String
from std_srvs.srv import Empty, Trigger
from visualization_msgs.msg import MarkerArray

from global_loc_interfaces.action import Localize

from ..core.localizer import Localizer, check_angle_step
from ..core.map_io import MapError, load_map_yaml
from ..core.matchers import resolve_method
from ..core.outcome import Cancelled, Outcome
from ..core.pose_history import PoseHistory
from ..core.scan import ScanError, scan_to_points
from ..core.scan_waiter import ScanWaiter
from ..core.search_region import SearchRegion
from ..core.transform import Rigid2D, format_pose
from .convert import (
    ended_result,
    map_from_msg,
    pose_from_msg,
    quaternion_to_yaw,
    result_to_msg,
    scan_from_msg,
    stamp_seconds,
)
from .memory import release_free_memory
from .motion import resolve_by_motion
from .mounting import LaserMounting
from .node_main import exit_process, run_node
from .parameters import declare_server_parameters
from .rviz import hypotheses_msg, local_map_msg, markers_msg
from .watch import LocalizationWatch

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def seconds(value: float) -> str:
    """A duration for a log line: 1.0, 12.5, 1e+308 (not 309 digits)."""
    return f'{value:.1f}' if value < 1e6 else f'{value:.3g}'


class GlobalLocServer(LifecycleNode):
    def __init__(self):
        super().__init__('global_loc_server')
        self.settings, self.config, supervisor_config = declare_server_parameters(self)
        self.group = ReentrantCallbackGroup()
        self.localizer: Localizer | None = None
        self.map_error = 'no map loaded yet'
        self.active = False
        self.stopping = threading.Event()     # set: running work ends (deactivate, cleanup, shutdown)
        self.busy = threading.Lock()
        self._in_flight, self._in_flight_lock = 0, threading.Lock()
        self.scans: ScanWaiter[LaserScan] = ScanWaiter()
        self.odom: ScanWaiter[Odometry] = ScanWaiter()        # the newest odometry (has any come?)
        self.odom_history = PoseHistory()                      # odometry by stamp
        self.watch = LocalizationWatch(self, supervisor_config)
        self.watch_timer = None
        self.cmd_vel_pub = self.create_publisher(Twist, self.settings.cmd_vel_topic, 10)
        self.mounting = LaserMounting(self, self.settings.base_frame, self.config.base_T_laser)
        self.pubs: dict = {}
        self.subs: list = []
        # The action and the services exist in every state, so a request while inactive gets a reason.
        self.action_server = ActionServer(self, Localize, 'localize', self.execute, callback_group=self.group,
                                          goal_callback=self.on_goal, cancel_callback=self.on_cancel)
        self.create_service(Trigger, '~/trigger', self.on_trigger, callback_group=self.group)
        self.create_service(Empty, '~/reinitialize_global_localization', self.on_reinitialize,
                            callback_group=self.group)
        if self.settings.autostart:
            self.trigger_configure()
            self.trigger_activate()
        else:
            self.get_logger().info('unconfigured: waiting for a lifecycle manager (autostart is false)')

    # ---- lifecycle -------------------------------------------------------------------------
    def on_configure(self, state) -> TransitionCallbackReturn:
        """Load the map (or subscribe to it) and precompute; create the publishers and the scan subscription."""
        s = self.settings
        self.stopping.clear()
        reliable = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
        self.pubs = {'initialpose': self.create_lifecycle_publisher(PoseWithCovarianceStamped, s.initialpose_topic,
                                                                    reliable),
                     'hypotheses': self.create_lifecycle_publisher(PoseArray, '~/hypotheses', LATCHED),
                     'markers': self.create_lifecycle_publisher(MarkerArray, '~/hypothesis_markers', LATCHED),
                     'local_map': self.create_lifecycle_publisher(OccupancyGrid, '~/local_map', LATCHED),
                     'status': self.create_lifecycle_publisher(String, '~/status', 10),
                     'diagnostics': self.create_lifecycle_publisher(DiagnosticArray, '/diagnostics', 10)}
        self.subs = [self.create_subscription(LaserScan, s.scan_topic, self.scans.put, qos_profile_sensor_data,
                                              callback_group=self.group),
                     self.create_subscription(Odometry, s.odom_topic, self.on_odom, 20, callback_group=self.group),
                     self.create_subscription(PoseWithCovarianceStamped, s.pose_topic, self.watch.on_pose, 10,
                                              callback_group=self.group)]
        self.watch_timer = self.create_timer(s.health_period_s, self.watch.tick, callback_group=self.group)
        if s.use_map_topic:
            self.subs.append(self.create_subscription(OccupancyGrid, s.map_topic, self.on_map, LATCHED,
                                                      callback_group=self.group))
            self.map_error = f'waiting for a map on {s.map_topic}'
            self.get_logger().info(f'waiting for the map on {s.map_topic}')
        else:
            self.load_map_file(s.map_yaml)
        self.get_logger().info('configured')
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        self.stopping.clear()
        self.watch.reset()
        self.active = True
        s = self.settings
        self.get_logger().info(f'ready: action "localize", services ~/trigger and ~/reinitialize_global_localization, '
                               f'scans on {s.scan_topic}, poses to {s.initialpose_topic}, '
                               f'default method {self.config.method}')
        return super().on_activate(state)

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        self.stop_work()
        self.get_logger().info('deactivated: not accepting work')
        return super().on_deactivate(state)

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        self.stop_work()
        for pub in self.pubs.values():
            self.destroy_lifecycle_publisher(pub)
        for sub in self.subs:
            self.destroy_subscription(sub)
        if self.watch_timer is not None:
            self.destroy_timer(self.watch_timer)
        self.pubs, self.subs, self.watch_timer = {}, [], None
        self.localizer, self.map_error = None, 'no map loaded (cleaned up)'
        self.get_logger().info('cleaned up: map dropped')
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        self.stop_work()
        return TransitionCallbackReturn.SUCCESS

    def stop_work(self, timeout: float = 2.0) -> None:
        """Stop accepting work and end a running localization (canceled); wait for it to end."""
        self.wind_down()
        if self.busy.acquire(timeout=timeout):
            self.busy.release()

    # ---- map and laser mounting --------------------------------------------------------------
    def load_map_file(self, path: str) -> None:
        try:
            self.set_map(load_map_yaml(path))
        except MapError as e:
            self.map_error = f'map not loaded: {e}'
            self.get_logger().error(f'{self.map_error}; requests are refused until a map is available')

    def set_map(self, occupancy_map) -> None:
        """Use `occupancy_map` from now on, with the default matcher precomputed now, not in the first request."""
        localizer = Localizer(occupancy_map, self.config)
        try:
            t0 = time.perf_counter()
            localizer.matcher(self.config.method)
            self.get_logger().info(f'map {occupancy_map.source}: {occupancy_map.width} x {occupancy_map.height} '
                                   f'cells at {occupancy_map.resolution} m; {self.config.method} ready in '
                                   f'{time.perf_counter() - t0:.2f} s')
        except ValueError as e:      # an unknown method (MethodError), bad bnb.* options
            self.get_logger().error(f'default method {self.config.method}: {e}')
        self.localizer = localizer

    def on_odom(self, msg: Odometry) -> None:
        self.odom_history.add(stamp_seconds(msg.header.stamp), pose_from_msg(msg.pose.pose))
        self.odom.put(msg)

    def on_map(self, msg: OccupancyGrid) -> None:
        """A new map from the map topic replaces the current one (a running localization keeps its own)."""
        try:
            self.set_map(map_from_msg(msg))
        except MapError as e:
            self.map_error = f'map not loaded: {e}'
            self.get_logger().error(self.map_error)

    # ---- requests -------------------------------------------------------------------------
    def on_goal(self, goal_request) -> GoalResponse:
        """Accept every goal; serve() ends it with an outcome if it cannot run."""
        return GoalResponse.ACCEPT

    def on_cancel(self, goal_handle) -> CancelResponse:
        """Accept every cancel; the search stops at its next progress report."""
        self.get_logger().info('cancel requested')
        return CancelResponse.ACCEPT

    @contextlib.contextmanager
    def in_flight(self):
        """Counts a request (goal or service call) until its handler returns (wind_down waits for none)."""
        with self._in_flight_lock:
            self._in_flight += 1
        try:
            yield
        finally:
            with self._in_flight_lock:
                self._in_flight -= 1

    def wind_down(self):
        """run_node's first step on SIGINT/SIGTERM, while the executor still spins: stop
        accepting work and end what runs (a goal ends canceled, "the server is stopping");
        returns whether it is all over."""
        self.active = False
        self.stopping.set()
        return lambda: self._in_flight == 0

    def execute(self, goal_handle):
        """The action: serve the goal, then end it as its outcome says."""
        with self.in_flight():
            return self._execute(goal_handle)

    def _execute(self, goal_handle):
        result = self.serve(goal_handle.request, lambda: goal_handle.is_cancel_requested,
                            lambda progress, stage, best, hypotheses=0: goal_handle.publish_feedback(
                                Localize.Feedback(progress=float(progress), stage=stage, hypotheses=int(hypotheses),
                                                  best_score=float(best) if math.isfinite(best) else 0.0)))
        if result.outcome == Outcome.LOCALIZED:
            goal_handle.succeed()
        elif result.outcome == Outcome.CANCELED and goal_handle.is_cancel_requested:
            goal_handle.canceled()
        else:
            goal_handle.abort()
        return result

    def on_trigger(self, request, response):
        """std_srvs/Trigger: localize the next scan with the defaults; the outcome in one line."""
        with self.in_flight():
            result = self.serve(Localize.Goal(publish_initialpose=True))
        response.success = bool(result.success)
        response.message = f'{Outcome(result.outcome).label}: {result.message}'
        if len(result.hypotheses.poses):
            p = result.pose.pose.pose
            pose = Rigid2D(p.position.x, p.position.y, quaternion_to_yaw(p.orientation))
            response.message += f'; {format_pose(pose)}, confidence {result.confidence:.2f}'
        return response

    def on_reinitialize(self, request, response):
        """std_srvs/Empty (nav2's ReinitializeGlobalLocalization): the same as ~/trigger."""
        with self.in_flight():
            self.serve(Localize.Goal(publish_initialpose=True))
        return response

    def serve(self, goal, cancelled=lambda: False, feedback=lambda *args: None) -> Localize.Result:
        """One localization, whoever asked; never raises: every end is an outcome."""
        if not self.active:
            return self.refuse(Outcome.NOT_ACTIVE, 'not active: the server is not in the active lifecycle state')
        if not self.busy.acquire(blocking=False):
            return self.refuse(Outcome.BUSY, 'busy: another localization is running (one at a time); retry when '
                                             'it ends')
        try:
            return self.localize(goal, lambda: cancelled() or self.stopping.is_set(), feedback)
        except Cancelled:
            reason = 'canceled' if not self.stopping.is_set() else 'canceled: the server is stopping'
            self.get_logger().info(reason)
            return ended_result(Outcome.CANCELED, reason)
        except Exception as e:   # an internal error must end this request, not the node
            self.get_logger().error(f'internal error: {e}\n{traceback.format_exc()}')
            return ended_result(Outcome.INTERNAL_ERROR, f'internal error: {type(e).__name__}: {e}')
        finally:
            self.busy.release()
            release_free_memory()

    def refuse(self, outcome: Outcome, message: str) -> Localize.Result:
        self.get_logger().warn(f'refused: {message}')
        return ended_result(outcome, message)

    def localize(self, goal, cancelled, feedback) -> Localize.Result:
        start = time.monotonic()
        localizer = self.localizer
        if localizer is None:
            return self.refuse(Outcome.NO_MAP, self.map_error)
        method = goal.method or self.config.method
        try:
            resolve_method(method)
            check_angle_step(goal.angle_step_deg or self.config.angle_step_deg)
            c = goal.search_center
            region = SearchRegion(Rigid2D(c.x, c.y, c.theta), goal.search_radius_m,
                                  math.radians(goal.search_yaw_tolerance_deg))
        except ValueError as e:    # MethodError is one
            return self.refuse(Outcome.BAD_GOAL, str(e))
        timeout = goal.timeout_s if goal.timeout_s > 0 else self.settings.scan_timeout_s
        topic = self.settings.scan_topic
        self.get_logger().info(f'localizing: method {method}, waiting up to {seconds(timeout)} s for a scan on {topic}')
        feedback(0.0, 'waiting_for_scan', 0.0)
        msg = self.scans.wait_after(start, timeout, cancelled)
        if msg is None:
            return self.refuse(Outcome.NO_SCAN, f'no scan on {topic} within {seconds(timeout)} s')
        feedback(0.05, 'preparing_scan', 0.0)   # local map or points, per method
        self.get_logger().info(f'matching a scan of {len(msg.ranges)} beams')
        last = [0.0]

        def progress(fraction, best):      # cancel between search steps; at most ~10 feedback messages a second
            if cancelled():
                raise Cancelled()
            if time.monotonic() - last[0] > 0.1 or fraction >= 1.0:
                last[0] = time.monotonic()
                feedback(0.05 + 0.9 * fraction, 'matching', best)

        base_T_laser = self.mounting.base_T_laser(msg.header.frame_id)
        try:
            scan = scan_from_msg(msg)
            result = localizer.localize(scan, method=method, angle_step_deg=goal.angle_step_deg or None,
                                        progress=progress, base_T_laser=base_T_laser, region=region)
        except ScanError as e:
            return self.refuse(Outcome.UNUSABLE_SCAN, f'scan unusable: {e}')
        if result.outcome == Outcome.AMBIGUOUS and goal.resolve_by_motion_s > 0:
            result, msg = resolve_by_motion(
                result, msg, base_T_laser, goal.resolve_by_motion_s, goal.rotate_in_place, localizer=localizer,
                scans=self.scans, odometry=self.odom_history,
                odometry_arrived=lambda timeout_s: self.odom.wait_after(0.0, timeout_s, cancelled) is not None,
                publish_cmd_vel=self.cmd_vel_pub.publish, rotate_speed=self.settings.rotate_speed,
                odom_topic=self.settings.odom_topic, cancelled=cancelled, feedback=feedback,
                log=self.get_logger().info)
            scan = scan_from_msg(msg)      # the poses are the robot's at the last scan used
        out = result_to_msg(result, self.settings.map_frame, msg.header.stamp, time.monotonic() - start)
        out.scan_stamp = msg.header.stamp
        out.scan_age_s = (self.get_clock().now() - Time.from_msg(msg.header.stamp)).nanoseconds * 1e-9
        self.show(result, scan, base_T_laser, msg.header.stamp, localizer.map)
        summary = result.message
        if result.pose is not None:
            summary += f': {format_pose(result.pose)}, score {result.score:.3f}, {result.time_s:.2f} s'
            if goal.publish_initialpose and (result.success or goal.publish_if_ambiguous):
                self.pubs['initialpose'].publish(out.pose)
                summary += f'; published on {self.settings.initialpose_topic}'
        self.get_logger().info(summary)
        return out

    def show(self, result, scan, base_T_laser: Rigid2D, stamp, occupancy_map) -> None:
        """The RViz topics for this localization."""
        frame = self.settings.map_frame
        self.pubs['hypotheses'].publish(hypotheses_msg(result, frame, stamp))
        self.pubs['markers'].publish(markers_msg(result, frame, stamp))
        if result.pose is not None:
            self.pubs['local_map'].publish(local_map_msg(scan_to_points(scan), occupancy_map.resolution,
                                                         self.config.opening_kernel, result.pose * base_T_laser,
                                                         frame, stamp, occupancy_map.diagonal_m))


def main(args=None):
    # Four threads: a running localization never starves the scan, cancel, service and lifecycle callbacks.
    exit_process(run_node(GlobalLocServer, lambda: MultiThreadedExecutor(num_threads=4), args=args))


if __name__ == '__main__':
    main()
