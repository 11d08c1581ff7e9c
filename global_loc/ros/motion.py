"""Settling an ambiguous answer by motion inside a localization request: the scans that
arrive while the robot moves - driven by someone else, or turned in place by the server
itself (one turn by the odometry, stopped with a zero twist however the request ends) -
fed to the core's hypothesis follower (core.motion.HypothesisFollower) with the odometry
at each scan's stamp. The collaborators are passed in; nothing here reads a node."""
from __future__ import annotations

import dataclasses
import math
import time
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

ODOMETRY_GRACE_S = 2.0     # a moment for a late first odometry message


def resolve_by_motion(result: LocalizationResult, first_msg, base_T_laser: Rigid2D, duration_s: float,
                      rotate_in_place: bool, *, localizer, scans: NewestMessage, odometry: PoseHistory,
                      odometry_arrived: Callable[[float], bool], publish_cmd_vel: Callable[[Twist], None],
                      rotate_speed: float, odom_topic: str, cancelled: Callable[[], bool], feedback,
                      log: Callable[[str], None]) -> tuple[LocalizationResult, object]:
    """Follow `result`'s hypotheses over the scans arriving for up to `duration_s`: (the
    winner as a localized result, or the result still ambiguous with the hypotheses left;
    the last scan message used - the poses are the robot's at its stamp).

    `odometry_arrived(timeout_s)`: whether any odometry has come, waiting up to timeout_s
    (raises CanceledError on cancel); `publish_cmd_vel(twist)`: the cmd_vel publisher's
    publish; `feedback(progress, stage, best_score, hypotheses)` as the action's."""
    first_stamp = stamp_seconds(first_msg.header.stamp)
    start_odometry = odometry.at(first_stamp) if odometry_arrived(ODOMETRY_GRACE_S) else None
    if start_odometry is None:
        return dataclasses.replace(result, message=f'{result.message} (no odometry on {odom_topic}: '
                                                   f'cannot resolve by motion)'), first_msg
    follower = HypothesisFollower(result, localizer, base_T_laser, start_odometry, first_stamp)
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
            yield Observation(points, odometry.at(stamp), stamp, msg)

    def on_step(f: HypothesisFollower):
        tracks = f.resolver.tracks
        feedback(0.95, Stage.RESOLVING_BY_MOTION, tracks[0].evidence if tracks else 0.0, len(tracks))

    try:
        follower.follow(live_observations(), on_step)
    finally:
        publish_cmd_vel(Twist())      # stop, however this ends (before the last search)
    outcome = follower.finish(search_fused=not cancelled())
    return outcome.result, first_msg if outcome.last is None else outcome.last.source
