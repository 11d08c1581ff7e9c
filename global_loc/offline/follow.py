"""`python -m global_loc localize --bag B|--carmen LOG --follow`: the server's resolution by
motion replayed on a recording, without ROS. Each start scan (every N-th) is localized;
when the answer is ambiguous its hypotheses are followed over the next scans with the
recorded odometry (core.motion.HypothesisFollower, the server's loop, timed by the scans'
stamps) for up to --follow-s seconds of recording; one JSON line per start.

Odometry: a bag's nav_msgs/Odometry (the base in the odometry frame), interpolated at each
scan's stamp; a CARMEN log's ODOM records (io/carmen.py: its FLASER odom fields are the
corrected pose - the truth - and are not used), whose corrected pose is the truth of each
line's pose.
"""
from __future__ import annotations

import itertools
import math
import sys
import time
from dataclasses import dataclass
from typing import Optional

from ..core.localizer import LocalizationResult
from ..core.motion import HypothesisFollower, Observation
from ..core.outcome import Outcome
from ..core.pose_history import PoseHistory
from ..core.scan import Scan, ScanError, scan_to_points
from ..core.transform import Rigid2D, pose_error


@dataclass
class Frame:
    index: int                       # on the scan topic / among the log's FLASER lines
    scan: Scan
    odometry: Optional[Rigid2D]      # base in the odometry frame at the scan's stamp; None: no odometry then
    truth: Optional[Rigid2D] = None  # base in the map frame, when the recording knows it (CARMEN)
    where: str = ''                  # where in the recording, for messages (a CARMEN log's line)


# A follow is bounded by distance and scan count as well as by the recording's stamps, which
# may repeat or go back (a CARMEN log whose stamps wrap to one value): --follow-s seconds at
# most at an indoor robot's top speed, and at a fast 2D laser's rate.
MAX_SPEED_MPS = 1.0
MAX_SCAN_RATE_HZ = 40.0


@dataclass(frozen=True)
class FollowBounds:
    seconds: float           # of the recording's stamps after the start scan's
    metres: float            # driven, by the odometry
    scans: int               # observations

    @staticmethod
    def for_seconds(seconds: float) -> 'FollowBounds':
        return FollowBounds(seconds, MAX_SPEED_MPS * seconds, math.ceil(MAX_SCAN_RATE_HZ * seconds))


def stamps_not_advancing(frames: list[Frame]) -> Optional[str]:
    """Where the recording's stamps first repeat or go back, said; None when they always advance."""
    bad = [(a, b) for a, b in itertools.pairwise(frames) if b.scan.stamp <= a.scan.stamp]
    if not bad:
        return None
    a, b = bad[0]
    return (f'the scans\' stamps do not always advance ({len(bad)} time(s)); first at scan {b.index}{b.where}: '
            f'{b.scan.stamp:.6f} after {a.scan.stamp:.6f}. Following is also bounded by distance and scan count')


def bag_frames(path: str, scan_topic: str, odom_topic: str) -> list[Frame]:
    """Every LaserScan of the recording with the odometry interpolated at its stamp (None
    outside the odometry's span: a pose there would be a guess)."""
    from ..io.bag import read_odometry, read_scans
    odometry = read_odometry(path, odom_topic)
    history = PoseHistory(keep_s=math.inf)
    for stamp, pose in odometry:
        history.add(stamp, pose)
    first, last = (odometry[0][0], odometry[-1][0]) if odometry else (math.inf, -math.inf)
    return [Frame(index, scan, history.at(scan.stamp) if first <= scan.stamp <= last else None)
            for index, scan in read_scans(path, scan_topic)]


def carmen_frames(path: str) -> list[Frame]:
    """Every FLASER scan of a CARMEN log with its raw odometry and corrected pose (laser poses:
    the base is the laser)."""
    from ..io.carmen import read_flaser
    return [Frame(i, r.scan, r.odometry, r.pose, f' (line {r.line})') for i, r in enumerate(read_flaser(path))]


def observations(frames: list[Frame], start: int, bounds: FollowBounds, end: Optional[int] = None,
                 ended: Optional[list] = None):
    """The frames after `start` (up to `end`) within `bounds` of it, as observations;
    unusable scans and scans without odometry skipped (the odometry spans the gap). Which
    bound ended them, if one did, is appended to `ended` ('time', 'distance', 'scans')."""
    t0, last, travelled, count = frames[start].scan.stamp, frames[start].odometry, 0.0, 0
    for frame in frames[start + 1:end]:
        if frame.scan.stamp - t0 > bounds.seconds:
            reason = 'time'
        elif frame.odometry is None:
            continue
        else:
            travelled += last.distance_to(frame.odometry)[0] if last is not None else 0.0
            last = frame.odometry
            reason = 'distance' if travelled > bounds.metres else 'scans' if count >= bounds.scans else ''
        if reason:
            if ended is not None:
                ended.append(reason)
            return
        try:
            points = scan_to_points(frame.scan)
        except ScanError:
            continue
        count += 1
        yield Observation(points, frame.odometry, frame.scan.stamp, frame)


def pose_fields(pose: Optional[Rigid2D], truth: Optional[Rigid2D]) -> dict:
    out = {} if pose is None else pose.as_dict()
    if pose is not None and truth is not None:
        d, a = pose_error(pose, truth)
        out.update(truth=truth.as_dict(), error_xy=round(d, 4), error_yaw_deg=round(a, 3))
    return out


def result_fields(result: LocalizationResult, truth: Optional[Rigid2D]) -> dict:
    return {'outcome': result.outcome.label, 'confidence': round(result.confidence, 4),
            'hypotheses': len(result.hypotheses), **pose_fields(result.pose, truth)}


def follow_start(localizer, frames: list[Frame], start: int, bounds: FollowBounds, base_T_laser: Rigid2D,
                 method: Optional[str] = None) -> dict:
    """One start scan localized and, when ambiguous, followed over the rest of the recording
    within `bounds`: its output line as a dict."""
    t0 = time.perf_counter()
    frame = frames[start]
    out = {'index': frame.index, 'stamp': round(frame.scan.stamp, 9)}
    try:
        single = localizer.localize(frame.scan, method, base_T_laser=base_T_laser)
    except ScanError as e:
        return {**out, 'single': {'outcome': Outcome.UNUSABLE_SCAN.label}, 'followed': False, 'settled': False,
                'outcome': Outcome.UNUSABLE_SCAN.label, 'error': str(e), 'time_s': round(time.perf_counter() - t0, 4)}
    out['single'] = result_fields(single, frame.truth)
    final, at, moved = single, frame, {'distance_m': 0.0, 'turn_deg': 0.0, 'scans': 0, 'follow_s': 0.0}
    followed = single.outcome == Outcome.AMBIGUOUS and frame.odometry is not None
    settled = False
    if followed:
        follower = HypothesisFollower(single, localizer, base_T_laser, frame.odometry, frame.scan.stamp)
        ended = []
        settled_early = follower.follow(observations(frames, start, bounds, ended=ended))
        outcome = follower.finish()
        final, settled = outcome.result, outcome.settled
        at = frame if outcome.last is None else outcome.last.source
        moved = {'distance_m': round(outcome.travelled_m, 3), 'turn_deg': round(math.degrees(outcome.turned_rad), 1),
                 'scans': outcome.scans, 'follow_s': round(outcome.elapsed_s, 3),
                 'ended': 'settled' if settled_early else ended[0] if ended else 'recording'}
    elif single.outcome == Outcome.AMBIGUOUS:
        out['error'] = 'no odometry at the start scan: not followed'
    return {**out, 'followed': followed, 'settled': settled, **result_fields(final, at.truth),
            'at_index': at.index, 'at_stamp': round(at.scan.stamp, 9), **moved, 'message': final.message,
            'time_s': round(time.perf_counter() - t0, 4)}


def start_indices(frames: list[Frame], every: int) -> list[int]:
    if every < 1:
        raise ValueError(f'--every must be at least 1, got {every}')
    return list(range(0, len(frames), every))



def carmen_map(path: str):
    """The occupancy map of a CARMEN log built from all its scans at their corrected poses
    (5 cm): the map a user of `--carmen` without `--map` localizes in."""
    from ..io.carmen import LogGrid, read_flaser
    records = read_flaser(path)
    grid = LogGrid(records, 0.05)
    return grid.occupancy_map(grid.counts(records), f'{path} (built from its scans)')


def carmen_scans(path: str, every: int):
    """(where, Scan, truth) per `every`-th FLASER scan of a CARMEN log: `localize --carmen`."""
    frames = carmen_frames(path)
    for i in start_indices(frames, every):
        yield {'index': frames[i].index, 'stamp': round(frames[i].scan.stamp, 9)}, frames[i].scan, frames[i].truth


def follow_main(args, localizer, base_T_laser: Optional[Rigid2D] = None) -> int:
    """`localize --follow`: one JSON line per start scan of the bag or log (`base_T_laser`:
    the laser's mounting, the laser itself by default - CARMEN's poses are the laser's)."""
    import json
    if args.follow_s <= 0:
        raise ValueError(f'--follow-s must be positive, got {args.follow_s}')
    if args.carmen:
        frames = carmen_frames(args.carmen)
    elif args.bag:
        frames = bag_frames(args.bag, args.topic, args.odom_topic)
    else:
        raise ValueError('--follow needs a recording with odometry: --bag or --carmen')
    method = localizer.matcher(args.method).name
    problem = stamps_not_advancing(frames)
    if problem:
        print(f'warning: {problem}', file=sys.stderr, flush=True)
    bounds = FollowBounds.for_seconds(args.follow_s)
    for start in start_indices(frames, args.every):
        row = follow_start(localizer, frames, start, bounds, base_T_laser or Rigid2D(), args.method)
        print(json.dumps({'method': method, **row}), flush=True)
    return 0
