"""The benchmark's ROS side in its own process, shared by the soak and fault suites: an
action client, the simulator's true pose by stamp, every /initialpose checked against the
true pose at its scan's stamp, kidnaps, maps on /map, parameters and lifecycle
transitions of the server, and a stand-in localizer (AMCL's part: /amcl_pose from the
last /initialpose it took)."""
from __future__ import annotations

import threading
import time
from collections import deque

import numpy as np

from ..core.transform import Rigid2D, pose_correct

TRUTH_MATCH_S = 0.3     # a pose stamped between the simulator's stamps: the nearest true pose this close


def rss_mb(pid: int) -> float:
    try:
        with open(f'/proc/{pid}/status') as f:
            return next(int(line.split()[1]) / 1024 for line in f if line.startswith('VmRSS:'))
    except (OSError, StopIteration):
        return float('nan')


def stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class Harness:
    """Spun in a background thread in an rclpy context of its own on the env's domain."""

    def __init__(self, env: dict, node_name: str = 'global_loc_bench'):
        import rclpy
        from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
        from lifecycle_msgs.srv import ChangeState
        from nav_msgs.msg import OccupancyGrid
        from rcl_interfaces.srv import SetParameters
        from rclpy.action import ActionClient
        from rclpy.executors import SingleThreadedExecutor

        from global_loc_interfaces.action import Localize

        from ..ros.convert import pose_from_msg
        from .processes import reliable
        self.Localize, self.PoseStamped = Localize, PoseStamped
        self.pose_from_msg = pose_from_msg
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=int(env['ROS_DOMAIN_ID']))
        self.node = rclpy.create_node(node_name, context=self.context)
        self.client = ActionClient(self.node, Localize, 'localize')
        self.truth, self.truths = None, deque(maxlen=4000)      # (stamp ns, pose), newest last
        self.published = []     # every /initialpose: (monotonic time, right at its stamp: True/False/None)
        self.wrong = []         # the wrong ones: pose, truth, stamp
        self.nonfinite = 0      # /initialpose messages with a NaN or infinite coordinate
        self.node.create_subscription(PoseStamped, '/sim/true_pose', self.on_truth, reliable(10, latched=True))
        self.node.create_subscription(PoseWithCovarianceStamped, '/initialpose', self.on_initialpose, reliable())
        self.set_pose = self.node.create_publisher(PoseStamped, '/sim/set_pose', 10)
        self.map_pub = self.node.create_publisher(OccupancyGrid, '/map', reliable(1, latched=True))
        self.params = self.node.create_client(SetParameters, '/global_loc_server/set_parameters')
        self.lifecycle = self.node.create_client(ChangeState, '/global_loc_server/change_state')
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        while not self.stopping.is_set():
            self.executor.spin_once(timeout_sec=0.02)

    # ---- the truth and the poses published ----------------------------------------------
    def on_truth(self, msg):
        self.truth = self.pose_from_msg(msg.pose)
        self.truths.append((stamp_ns(msg.header.stamp), self.truth))

    def truth_at(self, stamp) -> Rigid2D | None:
        """The simulator's true pose at a scan's stamp (None: no true pose that close)."""
        t = stamp_ns(stamp)
        best = min(list(self.truths), key=lambda st: abs(st[0] - t), default=None)
        return best[1] if best is not None and abs(best[0] - t) <= TRUTH_MATCH_S * 1e9 else None

    def right_at(self, pose: Rigid2D, stamp) -> bool | None:
        """Whether `pose` is within the thesis criterion of the true pose at `stamp`."""
        truth = self.truth_at(stamp)
        return None if truth is None else pose_correct(pose, truth)

    def on_initialpose(self, msg):
        pose = self.pose_from_msg(msg.pose.pose)
        if not pose.is_finite():
            self.nonfinite += 1
        ok = self.right_at(pose, msg.header.stamp)
        self.published.append((time.monotonic(), ok))
        if ok is False:          # what the report needs to find it in the server's log
            self.wrong.append({'pose': pose.as_tuple(), 'truth': self.truth_at(msg.header.stamp).as_tuple(),
                               'stamp_ns': stamp_ns(msg.header.stamp), 'received': time.monotonic()})

    @property
    def initialposes(self) -> int:
        return len(self.published)

    @property
    def wrong_initialposes(self) -> int:
        return sum(ok is False for _, ok in self.published)

    # ---- the simulator, the map, the server's services ------------------------------------
    def kidnap(self, pose: Rigid2D) -> None:
        from ..ros.convert import pose_to_msg
        msg = self.PoseStamped()
        msg.header.frame_id = 'map'
        msg.pose = pose_to_msg(pose)
        self.set_pose.publish(msg)
        deadline = time.monotonic() + 2.0      # until the simulator reports the new pose
        while time.monotonic() < deadline and (self.truth is None or not pose_correct(self.truth, pose, 0.05, 1.0)):
            time.sleep(0.01)
        time.sleep(0.1)      # a scan taken after the teleport

    def publish_map(self, occupancy_map) -> None:
        from ..ros.convert import map_to_msg
        self.map_pub.publish(map_to_msg(occupancy_map))

    def call(self, client, request, timeout: float = 15.0):
        """A service call's response, or None when none came within `timeout` (a hang)."""
        if not client.wait_for_service(timeout_sec=timeout):
            return None
        return self.wait(client.call_async(request), timeout)

    def set_parameters(self, values: dict, timeout: float = 15.0):
        """SetParameters results in order, or None (no answer)."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        params = [Parameter(name, value=v).to_parameter_msg() for name, v in values.items()]
        response = self.call(self.params, SetParameters.Request(parameters=params), timeout)
        return None if response is None else response.results

    def change_state(self, transition_id: int, timeout: float = 15.0):
        """Whether the lifecycle transition succeeded, or None (no answer). By transition id
        with an empty label, as nav2's lifecycle_manager asks."""
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState
        response = self.call(self.lifecycle, ChangeState.Request(transition=Transition(id=transition_id)), timeout)
        return None if response is None else response.success

    # ---- goals ----------------------------------------------------------------------------
    def wait(self, future, timeout: float):
        deadline = time.monotonic() + timeout
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.002)
        return future.result() if future.done() else None

    def send(self, timeout_s: float = 5.0, **fields):
        """Send a goal; its handle, or None (no server, or not accepted within 20 s)."""
        if not self.client.wait_for_server(timeout_sec=20.0):
            return None
        goal = self.Localize.Goal(timeout_s=timeout_s, **fields)
        return self.wait(self.client.send_goal_async(goal), 20.0)

    def close(self):
        self.stopping.set()
        self.thread.join(timeout=5.0)
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


class StandInLocalizer:
    """AMCL's part, on the harness's executor: takes poses from /initialpose and publishes
    the last one taken on /amcl_pose at 5 Hz; drops each incoming pose and each tick with
    probability `drop`."""

    def __init__(self, harness: Harness, rng: np.random.Generator, drop: float = 0.0):
        import rclpy
        from geometry_msgs.msg import PoseWithCovarianceStamped

        from .processes import reliable
        self.h, self.rng, self.drop = harness, rng, drop
        self.node = rclpy.create_node('stand_in_amcl', context=harness.context)
        self.pose, self.taken, self.dropped = None, [], 0      # taken: (monotonic time, right)
        self.node.create_subscription(PoseWithCovarianceStamped, '/initialpose', self.on_initialpose, reliable())
        self.pub = self.node.create_publisher(PoseWithCovarianceStamped, '/amcl_pose', reliable())
        self.node.create_timer(0.2, self.tick)
        harness.executor.add_node(self.node)

    def on_initialpose(self, msg):
        if self.rng.uniform() < self.drop:
            self.dropped += 1
            return
        self.pose = self.h.pose_from_msg(msg.pose.pose)
        self.taken.append((time.monotonic(), self.h.right_at(self.pose, msg.header.stamp)))

    def tick(self):
        from ..ros.convert import pose_with_covariance
        if self.pose is not None and self.rng.uniform() >= self.drop:
            self.pub.publish(pose_with_covariance(self.pose, np.diag([0.01, 0.01, 0.005]), 'map',
                                                  self.node.get_clock().now().to_msg()))

    def close(self):
        self.h.executor.remove_node(self.node)
        self.node.destroy_node()
