"""Settling an ambiguous answer by motion inside a localization request: the hypotheses
are followed with odometry and scored on every new scan (core.motion.MotionResolver)
while the robot moves - driven by someone else, or turned in place by the server itself
(one slow turn on cmd_vel, stopped with a zero twist however the request ends)."""
from __future__ import annotations

import dataclasses
import math
import time

from geometry_msgs.msg import Twist, Vector3

from ..core.localizer import Hypothesis, LocalizationResult
from ..core.motion import MotionConfig, MotionResolver, pose_fitter, settle
from ..core.scan import ScanError, scan_to_points
from ..core.transform import Rigid2D
from .convert import scan_from_msg, stamp_seconds


def resolve_by_motion(node, goal, result: LocalizationResult, first_scan, base_T_laser: Rigid2D, cancelled,
                      feedback) -> tuple[LocalizationResult, object]:
    """Follow `result`'s hypotheses for up to goal.resolve_by_motion_s: (the winner as a
    localized result, or the result still ambiguous with the hypotheses left; the last
    scan message used - the poses are the robot's at its stamp)."""
    odom = node.odom.wait_after(0.0, 2.0, cancelled)      # any odometry; a moment for a late first one
    if odom is None:
        return dataclasses.replace(result, message=f'{result.message} (no odometry on {node.settings.odom_topic}: '
                                                   f'cannot resolve by motion)'), first_scan
    matcher = node.localizer.matcher('bnb')
    resolver = MotionResolver([h.pose for h in result.hypotheses], MotionConfig.for_matcher(matcher.options))
    start = time.monotonic()
    deadline = start + goal.resolve_by_motion_s
    last_stamp, since = stamp_seconds(first_scan.header.stamp), start
    node.get_logger().info(f'resolving by motion: {len(resolver.tracks)} hypotheses, up to '
                           f'{goal.resolve_by_motion_s:.0f} s' + (', turning in place' if goal.rotate_in_place else ''))
    winner, leader, seen, checked = None, None, [], 0.0   # seen: (laser pose in the odometry frame, points)
    last_scan = first_scan
    try:
        while time.monotonic() < deadline and winner is None:
            turning = goal.rotate_in_place and resolver.turned < 2 * math.pi     # one turn, by the odometry
            node.cmd_vel_pub.publish(Twist(angular=Vector3(z=float(node.settings.rotate_speed) if turning else 0.0)))
            msg = node.scans.wait_after(since, max(0.0, deadline - since), cancelled)
            if msg is None:
                break
            since = time.monotonic()
            stamp = stamp_seconds(msg.header.stamp)
            last_scan = msg
            motion, last_stamp = node.odom_history.motion(last_stamp, stamp) or Rigid2D(), stamp
            try:
                points = scan_to_points(scan_from_msg(msg))
            except ScanError:
                continue
            odom = node.odom_history.at(stamp)
            if odom is not None:
                seen.append((odom * base_T_laser, points))
            leader = resolver.update(motion, pose_fitter(matcher, points, base_T_laser))
            if leader is not None and time.monotonic() - checked >= 1.0:    # a search: at most once a second
                checked = time.monotonic()
                winner = settle(node.localizer, seen, base_T_laser, leader.pose)
            feedback(0.95, 'resolving_by_motion', resolver.tracks[0].evidence if resolver.tracks else 0.0,
                     len(resolver.tracks))
    finally:
        node.cmd_vel_pub.publish(Twist())       # stop, however this ends
    hypotheses = [Hypothesis(t.pose, t.evidence) for t in resolver.tracks]
    moved = f'{resolver.travelled:.2f} m and {math.degrees(resolver.turned):.0f} deg'
    how = 'one place led and the scans seen, fused into one view, confirm it'
    if winner is None and not cancelled():
        winner = settle(node.localizer, seen, base_T_laser)
        how = 'the scans seen, fused into one view, match one place'
    if winner is None:
        return dataclasses.replace(result, hypotheses=hypotheses, pose=hypotheses[0].pose if hypotheses else None,
                                   message=f'ambiguous after {time.monotonic() - start:.0f} s of motion ({moved}): '
                                           f'{len(hypotheses)} place(s) still match; see the hypotheses'), last_scan
    return dataclasses.replace(winner, hypotheses=[Hypothesis(winner.pose, winner.score)] + hypotheses[1:],
                               message=f'localized by motion after {moved}: {how}'), last_scan
