"""Keeping a robot localized: the server follows the pose the localizer believes (its
`pose_topic`, moved forward by odometry between updates), checks the newest scan's fit
there every `health.period_s`, and publishes the state (core.supervisor.Health) on
/diagnostics and `~/status`. With `auto_relocalize`, it runs a global localization on
its own when it has never had a pose, or when the robot is lost, and publishes the pose
when confident - with the supervisor's guards (interval, attempts, waiting for the
localizer to take the pose)."""
from __future__ import annotations

import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import String

from global_loc_interfaces.action import Localize

from ..core.motion import pose_fitter
from ..core.outcome import Outcome
from ..core.scan import ScanError, scan_to_points
from ..core.supervisor import Health, Supervisor, SupervisorConfig
from .convert import pose_from_msg, scan_from_msg, stamp_seconds

LEVELS = {Health.LOCALIZED: DiagnosticStatus.OK, Health.LOST: DiagnosticStatus.ERROR}


class LocalizationWatch:
    def __init__(self, node, config: SupervisorConfig):
        self.node = node
        self.config = config
        self.supervisor = Supervisor(config, time.monotonic())
        self.belief = None        # (pose from the localizer, its stamp)
        self.lock = threading.Lock()

    def reset(self) -> None:
        """A fresh start (on activation)."""
        with self.lock:
            self.supervisor = Supervisor(self.config, time.monotonic())
            self.belief = None

    def on_pose(self, msg) -> None:
        """The localizer's pose: follow it from here."""
        with self.lock:
            self.belief = (pose_from_msg(msg.pose.pose), stamp_seconds(msg.header.stamp))
            self.supervisor.on_pose(time.monotonic())

    def believed_pose(self, stamp: float):
        """The localizer's last pose moved by the odometry to `stamp`, or None."""
        with self.lock:
            if self.belief is None:
                return None
            pose, since = self.belief
        motion = self.node.odom_history.motion(since, stamp)
        return pose if motion is None else pose * motion

    def tick(self) -> None:
        """Check the fit, publish the state, start a relocalization when one is due."""
        node = self.node
        if not node.active or node.localizer is None:
            return
        now = time.monotonic()
        msg = node.scans.latest()
        pose = None if msg is None else self.believed_pose(stamp_seconds(msg.header.stamp))
        if pose is not None:
            try:
                points = scan_to_points(scan_from_msg(msg))
                fit, _ = pose_fitter(node.localizer.matcher('bnb'), points,
                                     node.mounting.base_T_laser(msg.header.frame_id))(pose)
                with self.lock:
                    self.supervisor.on_fit(now, fit)
            except ScanError:
                pass
        self.publish()
        with self.lock:
            reason = self.supervisor.should_relocalize(now)
            if reason:
                self.supervisor.started_relocalization(now)
        if reason:
            node.get_logger().warn(f'relocalizing on its own: {reason}')
            self.publish()
            threading.Thread(target=self.relocalize, daemon=True, name='relocalize').start()

    def relocalize(self) -> None:
        node = self.node
        result = node.serve(Localize.Goal(publish_initialpose=True,
                                          resolve_by_motion_s=node.settings.relocalize_resolve_by_motion_s))
        with self.lock:
            self.supervisor.finished_relocalization(time.monotonic(), published=bool(result.success),
                                                    ambiguous=result.outcome == Outcome.AMBIGUOUS)
        node.get_logger().info(f'relocalization: {Outcome(result.outcome).label}: {result.message}')
        self.publish()

    def publish(self) -> None:
        with self.lock:
            s = self.supervisor
            health, fit, note, attempts = s.health, s.fit, s.note, s.attempts
        text = health.value + ('' if fit is None else f' fit={fit:.2f}') + (f' ({note})' if note else '')
        self.node.pubs['status'].publish(String(data=text))
        status = DiagnosticStatus(level=LEVELS.get(health, DiagnosticStatus.WARN), name='global_loc: localization',
                                  message=text, hardware_id=self.node.get_name())
        status.values = [KeyValue(key='state', value=health.value),
                         KeyValue(key='fit', value='' if fit is None else f'{fit:.3f}'),
                         KeyValue(key='relocalizations', value=str(attempts))]
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.node.get_clock().now().to_msg()
        self.node.pubs['diagnostics'].publish(array)
