"""`ros2 run global_loc test_global_loc`: send one Localize goal and print what happens
(or, with --json, one JSON object: outcome, pose, covariance, score, confidence,
hypotheses).

Exit code 0 when the server localized the robot, 1 when the goal ended without a pose
it is sure of (the message says why), 2 when no server answered.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time

import rclpy
from action_msgs.msg import GoalStatus
from geometry_msgs.msg import Pose2D
from rclpy.action import ActionClient
from rclpy.executors import ExternalShutdownException

from global_loc_interfaces.action import Localize

from ..core.transform import format_pose
from .convert import pose_from_msg, result_to_dict

STATUS = {GoalStatus.STATUS_SUCCEEDED: 'succeeded', GoalStatus.STATUS_ABORTED: 'aborted',
          GoalStatus.STATUS_CANCELED: 'canceled'}


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='test_global_loc', description='Ask global_loc server where the robot is.')
    parser.add_argument('--method', default='', help="matcher name (default: the server's)")
    parser.add_argument('--angle-step', type=float, default=0.0, help="Δα in degrees (default: the server's)")
    parser.add_argument('--timeout', type=float, default=0.0, help="seconds to wait for a scan (default: the server's)")
    parser.add_argument('--no-publish', action='store_true', help='do not publish the pose on /initialpose')
    parser.add_argument('--publish-if-ambiguous', action='store_true',
                        help='publish the best hypothesis even when the server is not confident')
    parser.add_argument('--server-timeout', type=float, default=10.0, help='seconds to wait for the server')
    parser.add_argument('--cancel-after', type=float, default=0.0, help='cancel the goal after this many seconds')
    parser.add_argument('--action', default='localize', help='action name')
    parser.add_argument('--near', type=float, nargs=3, metavar=('X', 'Y', 'YAW_DEG'), default=(0.0, 0.0, 0.0),
                        help='search prior: the centre (map frame, degrees) of --radius and --yaw-tolerance')
    parser.add_argument('--radius', type=float, default=0.0, help='search only within this many metres of --near')
    parser.add_argument('--yaw-tolerance', type=float, default=0.0,
                        help="search only headings within this many degrees of --near's")
    parser.add_argument('--resolve-by-motion', type=float, default=0.0, metavar='S',
                        help='when ambiguous, follow the hypotheses for up to S seconds while the robot moves')
    parser.add_argument('--rotate-in-place', action='store_true',
                        help='with --resolve-by-motion: the server turns the robot once, slowly (cmd_vel)')
    parser.add_argument('--json', action='store_true',
                        help='print only the result, as one JSON object (outcome, pose, covariance, ...)')
    return parser.parse_args(argv)


SERVER_GONE_S = 3.0    # the action server absent from the ROS graph this long: it is gone


def wait_while_served(node, client: ActionClient, future, limit_s: float = math.inf) -> bool:
    """Spin until `future` is done or `limit_s` passed; False when the server left the
    ROS graph meanwhile (it died: no result will come)."""
    deadline = time.monotonic() + limit_s
    absent_since = None
    while not future.done() and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
        if client.server_is_ready():
            absent_since = None
        elif absent_since is None:
            absent_since = time.monotonic()
        elif time.monotonic() - absent_since > SERVER_GONE_S:
            return False
    return True


def server_gone() -> int:
    print('error: the global_loc server disappeared before answering (crashed or stopped); no result', file=sys.stderr)
    return 2


def run(node, args) -> int:
    client = ActionClient(node, Localize, args.action)
    if not client.wait_for_server(timeout_sec=args.server_timeout):
        print(f'error: no global_loc server answered on action "{args.action}" within {args.server_timeout:.0f} s '
              f'(is `ros2 run global_loc server` running, with the same ROS_DOMAIN_ID?)', file=sys.stderr)
        return 2
    goal = Localize.Goal(method=args.method, angle_step_deg=args.angle_step, timeout_s=args.timeout,
                         publish_initialpose=not args.no_publish, publish_if_ambiguous=args.publish_if_ambiguous,
                         search_center=Pose2D(x=args.near[0], y=args.near[1], theta=math.radians(args.near[2])),
                         search_radius_m=args.radius, search_yaw_tolerance_deg=args.yaw_tolerance,
                         resolve_by_motion_s=args.resolve_by_motion, rotate_in_place=args.rotate_in_place)
    last_stage = ['']

    def on_feedback(fb):
        f = fb.feedback
        if args.json:
            return
        if f.stage != last_stage[0] or (f.progress >= 0.95 and f.stage != 'resolving_by_motion'):
            extra = f', {f.hypotheses} hypotheses' if f.stage == 'resolving_by_motion' else ''
            print(f'[{f.progress * 100:5.1f}%] {f.stage}  best score {f.best_score:.3f}{extra}', flush=True)
            last_stage[0] = f.stage

    send = client.send_goal_async(goal, feedback_callback=on_feedback)
    if not wait_while_served(node, client, send, args.server_timeout) or not send.done():
        print(f'error: the global_loc server did not answer the goal request within {args.server_timeout:.0f} s '
              f'(it stopped, or the request was lost while it was starting)', file=sys.stderr)
        return 2
    handle = send.result()
    if handle is None or not handle.accepted:
        print('error: the server rejected the goal', file=sys.stderr)
        return 1
    result_future = handle.get_result_async()
    if args.cancel_after > 0:
        if not wait_while_served(node, client, result_future, args.cancel_after):
            return server_gone()
        if not result_future.done():
            if not args.json:
                print(f'canceling after {args.cancel_after:.1f} s', flush=True)
            if not wait_while_served(node, client, handle.cancel_goal_async()):
                return server_gone()
    if not wait_while_served(node, client, result_future):
        return server_gone()
    response = result_future.result()
    result = response.result
    status = STATUS.get(response.status, str(response.status))
    if args.json:
        print(json.dumps(result_to_dict(result, status)), flush=True)
    else:
        if len(result.hypotheses.poses):
            print(f'pose:       {format_pose(pose_from_msg(result.pose.pose.pose))}  '
                  f'(frame {result.pose.header.frame_id})')
            print(f'score:      {result.score:.3f}   confidence: {result.confidence:.2f}   '
                  f'time: {result.elapsed_s:.2f} s')
            for i, (p, s) in enumerate(zip(result.hypotheses.poses, result.hypothesis_scores, strict=True)):
                print(f'  hypothesis {i + 1}: {format_pose(pose_from_msg(p))}  score {s:.3f}')
        print(f'{status}: {result.message}')
    return 0 if response.status == GoalStatus.STATUS_SUCCEEDED and result.success else 1


def main(argv=None):
    args = parse_args(sys.argv[1:] if argv is None else argv)
    rclpy.init()
    node = rclpy.create_node('test_global_loc')
    code = 1
    try:
        code = run(node, args)
    except (KeyboardInterrupt, ExternalShutdownException):
        print('interrupted', file=sys.stderr)
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    sys.exit(code)


if __name__ == '__main__':
    main()
