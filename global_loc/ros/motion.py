"""Settling an ambiguous answer by motion inside a localization request: the scans that
arrive while the robot moves - driven by someone else, or turned in place by the server
itself (one turn by the odometry, stopped with a zero twist however the request ends) -
fed to the core's hypothesis follower (core.motion.HypothesisFollower) with the odometry
at each scan's stamp. The collaborators are passed in; nothing here reads a node."""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Callable

from geometry_msgs.msg import Twist, Vector3

from ..core.localizer import LocalizationResult
from ..core.motion import HypothesisFollower, Observation
from ..core.newest_message import NewestMessage
from ..core.outcome import Stage
from ..core.pose_history import PoseHistory
from ..core.scan import ScanError, scan_to_points
from ..core.transform import Rigid2D
from .convert import scan_from_msg, stamp_seconds

# How long a scan waits for the odometry of its own stamp. A robot publishes the odometry
# of a moment after the scan of it (the simulator: in the same tick, just after), and a
# loaded machine delivers it later still; taken before it arrives, the pose would be the
# previous one, a tick of turning off (0.04 rad at 0.4 rad/s), on some scans and not on
# others - enough to blur the fused view that must confirm a winner.
ODOMETRY_LAG_S = 0.5


class OdometryAtStamp:
    """The odometry pose at a scan's stamp, once the odometry has reached that stamp (up to
    ODOMETRY_LAG_S); odometry stamped behind the scans for longer (another clock, a stalled
    driver) is held at its newest pose, said once in the log."""

    def __init__(self, odometry: PoseHistory, topic: str, cancelled: Callable[[], bool], log: Callable[[str], None]):
        self.odometry, self.topic, self.cancelled, self.log = odometry, topic, cancelled, log
        self.held = 0

    def __call__(self, stamp: float) -> Rigid2D:
        if not self.odometry.wait_until(stamp, ODOMETRY_LAG_S, self.cancelled):
            self.held += 1
            if self.held == 1:
                newest = self.odometry.newest_stamp()
                self.log(f'the odometry on {self.topic} is {stamp - newest:.2f} s behind a scan after waiting '
                         f'{ODOMETRY_LAG_S:g} s: its newest pose is used (are both stamped by the same clock?)')
        return self.odometry.at(stamp)


@dataclass(frozen=True)
class MotionContext:
    """What resolving by motion needs of the server, built when it is configured."""
    scans: NewestMessage                          # the primary laser's scans as they arrive
    odometry: PoseHistory                         # the odometry by stamp
    publish_cmd_vel: Callable[[Twist], None]      # the cmd_vel publisher's publish
    odom_topic: str                               # for messages
    log: Callable[[str], None]


@dataclass(frozen=True)
class MotionStart:
    """Where one resolution starts: the ambiguous result, the scan message it came from and
    that laser's mounting, the localizer that answered it."""
    result: LocalizationResult
    first_msg: object
    base_T_laser: Rigid2D
    localizer: object


def resolve_by_motion(context: MotionContext, start: MotionStart, request, rotate_speed: float,
                      cancelled: Callable[[], bool], feedback) -> tuple[LocalizationResult, object]:
    """Follow the start's hypotheses over the scans arriving for up to the request's
    resolve_by_motion_s (turning in place at `rotate_speed` when it asks): (the winner as a
    localized result, or the result still ambiguous with the hypotheses left; the last scan
    message used - the poses are the robot's at its stamp). A first odometry message is
    waited for as long as the request waits for a scan (a late odometry source);
    `feedback(progress, stage, best_score, hypotheses)` as the action's."""
    result, first_msg, odometry = start.result, start.first_msg, context.odometry
    duration_s, rotate_in_place, odometry_wait_s = (request.resolve_by_motion_s, request.rotate_in_place,
                                                    request.scan_timeout_s)
    odom_topic, log, scans, publish_cmd_vel = context.odom_topic, context.log, context.scans, context.publish_cmd_vel
    first_stamp = stamp_seconds(first_msg.header.stamp)
    if not odometry.wait_until(timeout_s=odometry_wait_s, cancelled=cancelled):
        return dataclasses.replace(result, message=f'{result.message} (no odometry on {odom_topic} within '
                                                   f'{odometry_wait_s:g} s: cannot resolve by motion)'), first_msg
    at_stamp = OdometryAtStamp(odometry, odom_topic, cancelled, log)
    start_odometry = at_stamp(first_stamp)
    follower = HypothesisFollower(result, start.localizer, start.base_T_laser, start_odometry, first_stamp)
    log(f'resolving by motion: {len(follower.resolver.tracks)} hypotheses, up to {duration_s:.0f} s'
        + (', turning in place' if rotate_in_place else ''))
    deadline = time.monotonic() + duration_s

    def live_observations():
        since = time.monotonic()
        while since < deadline:
            turning = rotate_in_place and follower.turned < 2 * math.pi      # one turn, by the odometry
            publish_cmd_vel(Twist(angular=Vector3(z=float(rotate_speed) if turning else 0.0)))
            msg = scans.wait_after(since, max(0.0, deadline - since), cancelled)   # CanceledError goes through
            if msg is None:
                return
            since = time.monotonic()
            stamp = stamp_seconds(msg.header.stamp)
            try:
                points = scan_to_points(scan_from_msg(msg))
            except ScanError:
                continue        # the odometry keeps the motion since the last scan used
            yield Observation(points, at_stamp(stamp), stamp, msg)

    def on_step(f: HypothesisFollower):
        tracks = f.resolver.tracks
        feedback(0.95, Stage.RESOLVING_BY_MOTION, tracks[0].evidence if tracks else 0.0, len(tracks))

    try:
        follower.follow(live_observations(), on_step)
    finally:
        publish_cmd_vel(Twist())      # stop, however this ends (before the last search)
    outcome = follower.finish(search_fused=not cancelled())
    return outcome.result, first_msg if outcome.last is None else outcome.last.source
