"""`ros2 run global_loc server`: the global-localization server, a lifecycle node.

States as in nav2: *configure* reads every parameter (an invalid one fails it, saying which)
and loads the maps (files or topic); *activate* serves; *deactivate* stops accepting work (a
running localization ends canceled); *cleanup* drops the maps. With `autostart` (default) it
configures and activates itself; otherwise a lifecycle manager drives it. Live parameters
apply to the next request (ros/parameters.py). Every way to ask - action `localize`,
`~/trigger`, `~/reinitialize_global_localization`, `~/localize_from_stored_pose`, the
start-up and the health watch (ros/watch.py) - takes one path (ros/request_path.py), one
localization at a time. docs/ARCHITECTURE.md has the threads, locks and hops."""
from __future__ import annotations

import functools
import threading
from typing import Optional

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped, Twist
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import LaserScan
from std_msgs.msg import Header, String
from std_srvs.srv import Empty, Trigger
from visualization_msgs.msg import MarkerArray

from global_loc_interfaces.action import Localize

from ..core.map_io import load_map_yaml
from ..core.map_set import MapSet
from ..core.map_slot import MapSlot
from ..core.mount import LaserMount
from ..core.newest_message import NewestMessage
from ..core.outcome import Outcome
from ..core.pose_history import PoseHistory
from ..core.request import Asked
from .convert import map_from_msg, pose_from_msg, stamp_seconds
from .guards import InFlight, answer_every_change_state, guard, wait_for_subscriber, warn_about_peers_once
from .map_build import build_map_set
from .motion import MotionContext
from .node_main import exit_process, run_node
from .parameters import BY_NAME, ConfigError, apply_live, check_set, declare_parameters, parameter_value, read_config
from .pose_file import PoseFile
from .request_path import Asker, Collaborators, RequestPath, asked_by_goal, publish_feedback, trigger_message
from .rviz import hypotheses_msg, local_map_msg, markers_msg
from .sensors import SensorInputs, SensorMounts, laser_fit, subscribe
from .watch import HealthWatch, WatchOutputs

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
# /initialpose: reliable and volatile, as AMCL subscribes it (a transient-local pose would
# reach no volatile subscriber that joins late anyway; the health watch retries instead).
INITIALPOSE = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)


class GlobalLocServer(LifecycleNode):
    def __init__(self):
        super().__init__('global_loc_server')
        answer_every_change_state(self)                 # nav2's lifecycle_manager asks by id
        self.start_problems = declare_parameters(self)
        self.config = None                              # ServerConfig while configured
        self.group = ReentrantCallbackGroup()
        self.maps: MapSlot[MapSet] = MapSlot(self.build_localizer, self.on_map_change)
        self.sensors = SensorInputs()                          # every sensor's newest message (the view)
        self.scans: NewestMessage[LaserScan] = NewestMessage()       # the primary laser's (watch, resolve-by-motion)
        self.odom_history = PoseHistory()                      # odometry by stamp
        self.errors: dict[str, int] = {}                       # callback name -> exceptions caught
        self.pubs, self.subs, self.own_timers = {}, [], []
        self.watch = self.mounts = self.cmd_vel_pub = None
        self.motion: Optional[MotionContext] = None     # while configured
        self.in_flight = InFlight()
        self.pose_file: Optional[PoseFile] = None        # stored_pose_file's, while configured
        self.guarded = functools.partial(guard, errors=self.errors, logger=self.get_logger())
        self.path = RequestPath(Collaborators(
            config=lambda: self.config, maps=self.maps, sensors=self.sensors,
            mount=lambda spec, frame: self.mounts.mount(spec, frame), laser_mount=self.laser_mount,
            odometry=self.odom_history, motion=lambda: self.motion,
            publish_pose=lambda msg: self.pubs['initialpose'].publish(msg), show=self.show,
            publish_map=lambda name: self.pubs['current_map'].publish(String(data=name)),
            clock_now=lambda: self.get_clock().now().nanoseconds * 1e-9, logger=self.get_logger(),
            pose_file=lambda: self.pose_file))
        self.add_on_set_parameters_callback(self.on_set_parameters)
        self.add_post_set_parameters_callback(self.on_parameters_set)
        # The action and the services exist in every state, so a request while inactive gets a reason.
        self.action_server = ActionServer(self, Localize, 'localize', self.execute, callback_group=self.group,
                                          goal_callback=lambda goal: GoalResponse.ACCEPT,
                                          cancel_callback=self.on_cancel)
        for kind, name, callback in ((Trigger, '~/trigger', self.on_trigger),
                                     (Empty, '~/reinitialize_global_localization', self.on_reinitialize),
                                     (Trigger, '~/localize_from_stored_pose', self.on_stored_pose_trigger)):
            self.create_service(kind, name, self.guarded(callback), callback_group=self.group)
        self.peer_check = warn_about_peers_once(self, self.guarded, self.group)
        if self.get_parameter('autostart').value:
            self.trigger_configure()
            if self.config is not None:
                self.trigger_activate()
        else:
            self.get_logger().info('unconfigured: waiting for a lifecycle manager (autostart is false)')

    # ---- lifecycle -------------------------------------------------------------------------
    def on_configure(self, state) -> TransitionCallbackReturn:
        """Read every parameter; create the publishers, subscriptions and timers; load the map."""
        try:
            if self.start_problems:
                raise ConfigError(next(iter(self.start_problems.values())))
            config = read_config(self)
        except ConfigError as e:
            self.path.inactive_reason = f'not configured: {e} (set it and configure again)'
            self.get_logger().error(f'configure failed: {e}; set it (ros2 param set) and configure again')
            return TransitionCallbackReturn.FAILURE
        self.config = config
        self.path.stopping.clear()
        if self.mounts is None:        # one tf listener for the node's life
            self.mounts = SensorMounts(self, self.guarded)
        self.mounts.configure(config)
        self.sensors.configure(config.sensors)
        self.create_interfaces(config)
        self.pose_file = PoseFile(config['stored_pose_file'], self.odom_history, self.get_logger()) \
            if config['stored_pose_file'] else None
        if config['use_map_topic']:
            self.maps.clear(f'waiting for a map on {config["map_topic"]}')
            self.get_logger().info(f'waiting for the map on {config["map_topic"]}')
        else:
            files = config.map_files
            self.maps.load_now(lambda: {name: load_map_yaml(path) for name, path in files.items()})
        self.path.inactive_reason = 'not active: configured, not yet activated'
        self.get_logger().info('configured')
        return TransitionCallbackReturn.SUCCESS

    def create_interfaces(self, config) -> None:
        g = self.group
        self.pubs = {'initialpose': self.create_lifecycle_publisher(PoseWithCovarianceStamped,
                                                                    config['initialpose_topic'], INITIALPOSE),
                     'hypotheses': self.create_lifecycle_publisher(PoseArray, '~/hypotheses', LATCHED),
                     'markers': self.create_lifecycle_publisher(MarkerArray, '~/hypothesis_markers', LATCHED),
                     'local_map': self.create_lifecycle_publisher(OccupancyGrid, '~/local_map', LATCHED),
                     'status': self.create_lifecycle_publisher(String, '~/status', 10),
                     'current_map': self.create_lifecycle_publisher(String, '~/current_map', LATCHED),
                     'diagnostics': self.create_lifecycle_publisher(DiagnosticArray, '/diagnostics', 10)}
        self.cmd_vel_pub = self.create_publisher(Twist, config['cmd_vel_topic'], 10)
        self.motion = MotionContext(self.scans, self.odom_history, self.cmd_vel_pub.publish, config['odom_topic'],
                                    self.get_logger().info)
        self.watch = HealthWatch(config.supervisor, config['map_frame'], self.fit_at, self.odom_history, WatchOutputs(
            self.pubs['status'].publish, self.pubs['diagnostics'].publish, lambda: self.get_clock().now().to_msg(),
            self.get_logger(), self.get_name(), extra_values=lambda: {
                **{f'errors.{k}': n for k, n in self.errors.items()}, **self.sensors.diagnostics()}))
        self.subs = subscribe(self, config.sensors, self.sensors, self.scans, self.guarded, g) + [
                     self.create_subscription(Odometry, config['odom_topic'], self.guarded(self.on_odom), 20,
                                              callback_group=g),
                     self.create_subscription(PoseWithCovarianceStamped, config['pose_topic'],
                                              self.guarded(self.watch.on_pose), 10, callback_group=g)]
        if config['use_map_topic']:
            # one at a time, in arrival order; the MapSlot builds off the executor and keeps the newest
            self.subs.append(self.create_subscription(OccupancyGrid, config['map_topic'], self.guarded(self.on_map),
                                                      LATCHED, callback_group=MutuallyExclusiveCallbackGroup()))
        self.own_timers = [self.create_timer(config['health.period_s'], self.guarded(self.on_health_tick),
                                         callback_group=g)]

    def on_activate(self, state) -> TransitionCallbackReturn:
        self.path.stopping.clear()
        self.watch.reset(self.config.supervisor)
        self.path.active = True
        c = self.config
        self.get_logger().info(f'ready: action "localize", services ~/trigger and ~/reinitialize_global_localization, '
                               f'sensors {", ".join(s.topic for s in c.sensors)}, poses to {c["initialpose_topic"]}, '
                               f'default method {c["method"]}')
        if self.pose_file is not None:      # start-up from the last pose, off the executor
            self.get_logger().info(f'starting from the stored pose in {self.pose_file.path} (or a full search)')
            threading.Thread(target=self.start_up, args=(self.pubs['initialpose'],), daemon=True, name='boot').start()
        return super().on_activate(state)

    def start_up(self, pose_publisher) -> None:
        """The start-up localization, once the pose topic has a subscriber (a bounded wait)."""
        if not wait_for_subscriber(pose_publisher, self.path.stopping):
            self.get_logger().warn(f'start-up: nobody subscribes to {pose_publisher.topic_name}; localizing anyway')
        self.serve_unattended(Asked(origin='start-up', from_stored_pose=True))

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        self.stop_work()
        self.path.inactive_reason = 'not active: deactivated'
        self.get_logger().info('deactivated: not accepting work')
        return super().on_deactivate(state)

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        self.stop_work()
        for pub in self.pubs.values():
            self.destroy_lifecycle_publisher(pub)
        for destroy, handles in ((self.destroy_subscription, self.subs), (self.destroy_timer, self.own_timers)):
            for handle in handles:
                destroy(handle)
        if self.cmd_vel_pub is not None:
            self.destroy_publisher(self.cmd_vel_pub)
        self.pubs, self.subs, self.own_timers, self.cmd_vel_pub, self.config = {}, [], [], None, None
        self.motion = None
        self.maps.clear('no map loaded (cleaned up)')
        self.path.inactive_reason = 'not active: cleaned up (configure it again)'
        self.get_logger().info('cleaned up: map dropped')
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        self.stop_work()
        return TransitionCallbackReturn.SUCCESS

    def stop_work(self, timeout: float = 2.0) -> None:
        """Stop accepting work and end what runs (canceled), waiting `timeout` s for it (RequestPath.epoch)."""
        self.wind_down()
        if self.path.busy.acquire(timeout=timeout):
            self.path.busy.release()
        else:
            self.get_logger().warn(f'a localization still runs {timeout:g} s after the stop: it ends canceled')

    def wind_down(self):
        """run_node's first step on SIGINT/SIGTERM, while the executor spins: stop accepting work,
        end what runs (a goal ends canceled, "the server is stopping"); returns whether it is over."""
        self.path.stop()
        return lambda: self.in_flight.count == 0

    def close(self) -> None:
        self.maps.close()

    # ---- parameters ----------------------------------------------------------------------
    def on_set_parameters(self, params):
        """Refuse what the server cannot run with, and while configured what it reads only at
        configure (the reasons say why); live ones apply to the next request."""
        current = self.config.values if self.config is not None else \
            {name: parameter_value(self, name) for name in BY_NAME}
        return check_set(current, params, configured=self.config.prepared if self.config is not None else ())

    def on_parameters_set(self, params) -> None:
        for p in params:
            self.start_problems.pop(p.name, None)     # a corrected value: the next configure reads it
        if self.config is None:
            return
        self.config = apply_live(self.config, params)
        if self.watch is not None:
            self.watch.reconfigure(self.config.supervisor)
        self.mounts.configure(self.config)
        names = ', '.join(f'{p.name}={p.value}' for p in params)
        self.get_logger().info(f'parameters set: {names}')

    # ---- maps, odometry, health -------------------------------------------------------------
    def build_localizer(self, load) -> MapSet:
        """The maps `load()` gives, prepared (ros/map_build.py): in the map builder, off the executor."""
        return build_map_set(load, self.config, self.get_logger())

    def on_map_change(self, installed, note: str, dropped: bool) -> None:
        if installed.built is None and not dropped:
            self.get_logger().error(f'{note}; requests are refused until a map is available')
        else:
            self.get_logger().info(note)

    def on_map(self, msg: OccupancyGrid) -> None:
        """A map from the map topic: the newest received is used once it is prepared."""
        generation = self.maps.submit(lambda: map_from_msg(msg))
        self.get_logger().info(f'map {generation} received on {self.config["map_topic"]}: '
                               f'{msg.info.width} x {msg.info.height} cells')

    def on_odom(self, msg: Odometry) -> None:
        self.odom_history.add(stamp_seconds(msg.header.stamp), pose_from_msg(msg.pose.pose))

    def fit_at(self, scan_msg, pose):
        """The watch's fit of a primary-laser scan at a base pose (None while no map is ready)."""
        localizer = self.maps.current().built
        return None if localizer is None else laser_fit(localizer.tracker(on=self.config['served_map']),
                                                        self.laser_mount, scan_msg, pose)

    def laser_mount(self, frame: str) -> LaserMount:
        return self.mounts.laser_mount(self.config.sensors, frame)

    def on_health_tick(self) -> None:
        if not self.path.active:
            return
        reason = self.watch.tick(self.scans.latest())
        if reason:
            self.get_logger().warn(f'relocalizing on its own: {reason}')
            threading.Thread(target=self.relocalize, daemon=True, name='relocalize').start()

    def relocalize(self) -> None:
        result = self.serve_unattended(Asked(origin='relocalization',
                                             resolve_by_motion_s=self.config['relocalize.resolve_by_motion_s']))
        self.watch.finished(Outcome(result.outcome), published=bool(result.success))

    def show(self, result, points, base_T_laser, stamp, occupancy_map) -> None:
        """The RViz topics for this localization."""
        header = Header(frame_id=self.config['map_frame'], stamp=stamp)
        self.pubs['hypotheses'].publish(hypotheses_msg(result, header))
        self.pubs['markers'].publish(markers_msg(result, header))
        if result.pose is not None:
            self.pubs['local_map'].publish(local_map_msg(points, occupancy_map.resolution,
                                                         self.config['opening_kernel'], result.pose * base_T_laser,
                                                         header, occupancy_map.diagonal_m))

    # ---- requests -------------------------------------------------------------------------
    def on_cancel(self, goal_handle) -> CancelResponse:
        """Accept every cancel; the search stops at its next progress report."""
        self.get_logger().info('cancel requested')
        return CancelResponse.ACCEPT

    def execute(self, goal_handle):
        """The action: serve the goal, then end it as its outcome says."""
        with self.in_flight():
            result = self.path.serve(asked_by_goal(goal_handle.request),
                                     Asker(lambda: goal_handle.is_cancel_requested,
                                           functools.partial(publish_feedback, goal_handle)))
        if result.outcome == Outcome.LOCALIZED:
            goal_handle.succeed()
        elif result.outcome == Outcome.CANCELED and goal_handle.is_cancel_requested:
            goal_handle.canceled()
        else:
            goal_handle.abort()
        return result

    def on_trigger(self, request, response):
        """std_srvs/Trigger: localize the next scan with the defaults; the outcome in one line."""
        return self.answer_trigger(Asked(origin='trigger'), response)

    def on_stored_pose_trigger(self, request, response):
        """std_srvs/Trigger: as ~/trigger, the stored pose tried first (stored_pose_file)."""
        return self.answer_trigger(Asked(origin='stored pose', from_stored_pose=True), response)

    def answer_trigger(self, asked: Asked, response):
        with self.in_flight():
            result = self.path.serve(asked)
        response.success = bool(result.success)
        pose = pose_from_msg(result.pose.pose.pose) if len(result.hypotheses.poses) else None
        response.message = trigger_message(result, pose)
        return response

    def serve_unattended(self, asked: Asked) -> Localize.Result:
        """A request nobody waits on (start-up, relocalization, nav2's reinitialize): its end logged."""
        with self.in_flight():
            result = self.path.serve(asked)
        self.get_logger().info(f'{asked.origin}: {Outcome(result.outcome).label}: {result.message}')
        return result

    def on_reinitialize(self, request, response):
        """std_srvs/Empty (nav2's ReinitializeGlobalLocalization): the same as ~/trigger."""
        self.serve_unattended(Asked(origin='reinitialize'))
        return response


def main(args=None):
    # Four threads: a running localization never starves the scan, cancel, service and lifecycle callbacks.
    exit_process(run_node(GlobalLocServer, lambda: MultiThreadedExecutor(num_threads=4), args=args))


if __name__ == '__main__':
    main()
