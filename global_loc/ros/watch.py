"""Keeping a robot localized: follow the pose the localizer believes (its `pose_topic`,
moved forward by odometry between updates), check the newest scan's fit there every
`health.period_s`, publish the state (core.supervisor.Health) on /diagnostics and
`~/status`, and say when a relocalization is due (`auto_relocalize`, with the
supervisor's guards). The watch never starts one itself: `tick` returns the reason and
the server runs it through its one request path, then reports the end (`finished`).

It gets what it needs passed in - a fit function, the odometry, publish callables, a
logger - and reads nobody's fields, so it is tested without a node.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable, Optional

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import String

from ..core.outcome import Outcome
from ..core.pose_history import PoseHistory
from ..core.supervisor import Health, Supervisor, SupervisorConfig
from ..core.transform import Rigid2D
from .convert import pose_from_msg, stamp_seconds

LEVELS = {Health.LOCALIZED: DiagnosticStatus.OK, Health.LOST: DiagnosticStatus.ERROR}
WARN_EVERY_S = 10.0
# A relocalization that ended so never looked at a scan: not an attempt (supervisor).
NOT_COUNTED = {Outcome.NO_SCAN, Outcome.NOT_ACTIVE, Outcome.CANCELED, Outcome.BUSY, Outcome.NO_MAP}

# (scan message, robot base pose in the map) -> fit in 0..1, or None when it cannot be computed now
FitFn = Callable[[object, Rigid2D], Optional[float]]


@dataclass(frozen=True)
class WatchOutputs:
    """Where the watch says what it sees."""
    publish_status: Callable[[String], None]               # ~/status
    publish_diagnostics: Callable[[DiagnosticArray], None]  # /diagnostics
    now_msg: Callable[[], object]                          # the node's clock as a stamp
    logger: object
    name: str                                              # the diagnostics' hardware_id
    extra_values: Callable[[], dict] = dict                # more key/values for /diagnostics


class HealthWatch:
    def __init__(self, config: SupervisorConfig, map_frame: str, fit: FitFn, odometry: PoseHistory,
                 outputs: WatchOutputs, clock: Callable[[], float] = time.monotonic):
        self.config, self.map_frame, self.fit, self.odometry = config, map_frame, fit, odometry
        self.out, self.logger, self.clock = outputs, outputs.logger, clock
        self.lock = threading.Lock()
        self.supervisor = Supervisor(config, clock())
        self.belief: Optional[tuple[Rigid2D, float]] = None      # (localizer's pose, its stamp)

    def reset(self, config: Optional[SupervisorConfig] = None) -> None:
        """A fresh start (activation), with `config` when it changed."""
        with self.lock:
            self.config = config or self.config
            self.supervisor = Supervisor(self.config, self.clock())
            self.belief = None

    def reconfigure(self, config: SupervisorConfig) -> None:
        """New thresholds and guards (a live parameter change); the state is kept."""
        with self.lock:
            self.config = self.supervisor.config = config

    def on_pose(self, msg) -> None:
        """The localizer's pose: follow it from here. One in another frame than the map is
        not comparable and is ignored; one stamped 0 is taken as of the newest odometry
        (a zero stamp would apply all the stored odometry as motion)."""
        frame = msg.header.frame_id
        if frame and frame.lstrip('/') != self.map_frame.lstrip('/'):
            self.logger.warn(f'ignoring a localizer pose in frame "{frame}" (not "{self.map_frame}")',
                             throttle_duration_sec=WARN_EVERY_S)
            return
        stamp = stamp_seconds(msg.header.stamp)
        if stamp == 0.0:
            self.logger.warn('localizer pose stamped 0: taken as of the newest odometry',
                             throttle_duration_sec=WARN_EVERY_S)
            stamp = self.odometry.newest_stamp() or 0.0
        with self.lock:
            self.belief = (pose_from_msg(msg.pose.pose), stamp)
            self.supervisor.on_pose(self.clock())

    def believed_pose(self, stamp: float) -> Optional[Rigid2D]:
        """The localizer's last pose moved by the odometry to `stamp`, or None."""
        with self.lock:
            if self.belief is None:
                return None
            pose, since = self.belief
        motion = self.odometry.motion(since, stamp)
        return pose if motion is None else pose * motion

    def tick(self, scan_msg) -> Optional[str]:
        """Check the fit of `scan_msg` (the newest scan, None before the first), publish the
        state; the reason a relocalization should start now (it is then counted as
        started), or None."""
        now = self.clock()
        pose = None if scan_msg is None else self.believed_pose(stamp_seconds(scan_msg.header.stamp))
        fit = None if pose is None else self.fit(scan_msg, pose)
        with self.lock:
            if fit is not None:
                self.supervisor.on_fit(now, fit)
        self.publish()          # the state the fit gives (lost, ...), before a relocalization starts
        with self.lock:
            reason = self.supervisor.should_relocalize(now, scan_arrived=scan_msg is not None)
            if reason:
                self.supervisor.started_relocalization(now)
        if reason:
            self.publish()
        return reason

    def finished(self, outcome: Outcome, published: bool) -> None:
        """The relocalization `tick` asked for ended so."""
        with self.lock:
            self.supervisor.finished_relocalization(self.clock(), published=published,
                                                    ambiguous=outcome == Outcome.AMBIGUOUS,
                                                    counted=outcome not in NOT_COUNTED)
        self.publish()

    def publish(self) -> None:
        with self.lock:
            s = self.supervisor
            health, fit, note, attempts = s.health, s.fit, s.note, s.attempts
        text = health.value + ('' if fit is None else f' fit={fit:.2f}') + (f' ({note})' if note else '')
        self.out.publish_status(String(data=text))
        status = DiagnosticStatus(level=LEVELS.get(health, DiagnosticStatus.WARN), name='global_loc: localization',
                                  message=text, hardware_id=self.out.name)
        values = {'state': health.value, 'fit': '' if fit is None else f'{fit:.3f}',
                  'relocalizations': str(attempts), **self.out.extra_values()}
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.out.now_msg()
        self.out.publish_diagnostics(array)
