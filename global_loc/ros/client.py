"""`ros2 run global_loc test_global_loc`: send one Localize goal and print what happens
(or, with --json, one JSON object: outcome, pose, covariance, score, confidence,
hypotheses). A command line over global_loc.ros.api.GlobalLocalizer.

Ctrl-C (SIGINT) or SIGTERM cancels the goal, waits up to 2 s for the server to accept
the cancel, then exits: an interrupted client leaves no goal turning the robot.

Exit codes:
  0  the server localized the robot;
  1  the goal ended without a pose it is sure of (the message says why), was rejected,
     or the client was interrupted (the goal canceled);
  2  bad arguments;
  3  no server answered: none within --server-timeout, it disappeared before the result,
     or it left the goal request unanswered (with --json: {"outcome": "no_server" |
     "server_gone" | "goal_unanswered", "success": false, "message": ...}).
"""
from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import threading

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.signals import SignalHandlerOptions

from ..core.outcome import Stage
from ..core.transform import Rigid2D, format_pose
from .api import GlobalLocalizer, GlobalLocError, GoalRejected, LocalizeGoal, LocalizeResult, ServerNames

EXIT_LOCALIZED, EXIT_NOT_LOCALIZED, EXIT_BAD_ARGUMENTS, EXIT_NO_SERVER = 0, 1, 2, 3


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
    parser.add_argument('--map', action='append', default=[], dest='maps', metavar='NAME',
                        help="with a map set (the server's maps): search this map only; repeat for several")
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


def feedback_printer(quiet: bool):
    """Prints a line per new stage (and the end of matching), unless `quiet`."""
    last_stage = ['']

    def on_feedback(f):
        if quiet:
            return
        if f.stage != last_stage[0] or (f.progress >= 0.95 and f.stage != Stage.RESOLVING_BY_MOTION):
            extra = f', {f.hypotheses} hypotheses' if f.stage == Stage.RESOLVING_BY_MOTION else ''
            print(f'[{f.progress * 100:5.1f}%] {f.stage}  best score {f.best_score:.3f}{extra}', flush=True)
            last_stage[0] = f.stage
    return on_feedback


def print_result(result: LocalizeResult, as_json: bool) -> None:
    if as_json:
        print(json.dumps(result.as_dict()), flush=True)
        return
    if result.pose is not None:
        print(f'pose:       {format_pose(result.pose)}  (frame {result.frame_id}, map {result.map})')
        print(f'score:      {result.score:.3f}   confidence: {result.confidence:.2f}   '
              f'time: {result.elapsed_s:.2f} s')
        for i, ((p, s), on) in enumerate(zip(result.hypotheses, result.padded_maps(), strict=False)):
            print(f'  hypothesis {i + 1}: {format_pose(p)}  score {s:.3f}' + (f'  map {on}' if on else ''))
    print(f'{result.status}: {result.message}')


def run(localizer: GlobalLocalizer, args) -> int:
    timer = None
    if args.cancel_after > 0:
        def cancel():
            if localizer.cancel() and not args.json:
                print(f'canceling after {args.cancel_after:.1f} s', flush=True)
        timer = threading.Timer(args.cancel_after, cancel)
        timer.daemon = True
        timer.start()
    try:
        near = Rigid2D(args.near[0], args.near[1], math.radians(args.near[2]))
        goal = LocalizeGoal(
            method=args.method, angle_step_deg=args.angle_step, timeout_s=args.timeout, publish=not args.no_publish,
            publish_if_ambiguous=args.publish_if_ambiguous, near=near,
            radius_m=args.radius, yaw_tolerance_deg=args.yaw_tolerance, resolve_by_motion_s=args.resolve_by_motion,
            rotate_in_place=args.rotate_in_place, maps=args.maps)
        result = localizer.localize(goal, feedback=feedback_printer(args.json))
    except GlobalLocError as e:
        print(f'error: {e}', file=sys.stderr)
        if args.json:
            print(json.dumps({'outcome': e.label, 'success': False, 'message': str(e)}), flush=True)
        return EXIT_NOT_LOCALIZED if isinstance(e, GoalRejected) else EXIT_NO_SERVER
    finally:
        if timer is not None:
            timer.cancel()
    print_result(result, args.json)
    return EXIT_LOCALIZED if result.status == 'succeeded' and result.success else EXIT_NOT_LOCALIZED


def main(argv=None):
    args = parse_args(sys.argv[1:] if argv is None else argv)
    # No rclpy signal handlers: SIGINT and SIGTERM are the localizer's while the goal runs
    # (they cancel it), and outside of it they end the process as they normally would.
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    localizer = GlobalLocalizer('test_global_loc', server=ServerNames(action=args.action),
                                server_timeout_s=args.server_timeout, cancel_signals=(signal.SIGINT, signal.SIGTERM))
    code = EXIT_NOT_LOCALIZED
    try:
        code = run(localizer, args)
    except KeyboardInterrupt as e:
        print(f'interrupted: {e}' if str(e) else 'interrupted', file=sys.stderr)
    except ExternalShutdownException:
        print('interrupted: ROS was shut down', file=sys.stderr)
    finally:
        localizer.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    sys.exit(code)


if __name__ == '__main__':
    main()
