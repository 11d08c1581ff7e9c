"""`python -m global_loc localize --bag B|--carmen LOG --follow`: the server's resolution by
motion replayed on a recording, without ROS. Each start scan (every N-th) is localized;
when the answer is ambiguous its hypotheses are followed over the next scans with the
recorded odometry (core.motion.HypothesisFollower, the server's loop, timed by the scans'
stamps) for up to --follow-s seconds of recording; one JSON line per start.

Odometry: a bag's nav_msgs/Odometry (the base in the odometry frame), interpolated at each
scan's stamp; a CARMEN log's ODOM records (bench.carmen: its FLASER odom fields are the
corrected pose - the truth - and are not used), whose corrected pose is the truth of each
line's pose.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Optional

from .bagfile import BagError
from .core.localizer import LocalizationResult
from .core.motion import HypothesisFollower, Observation
from .core.outcome import Outcome
from .core.pose_history import PoseHistory
from .core.scan import Scan, ScanError, scan_to_points
from .core.transform import Rigid2D, pose_error

ODOMETRY = 'nav_msgs/msg/Odometry'


@dataclass
class Frame:
    index: int                       # on the scan topic / among the log's FLASER lines
    scan: Scan
    odometry: Optional[Rigid2D]      # base in the odometry frame at the scan's stamp; None: no odometry then
    truth: Optional[Rigid2D] = None  # base in the map frame, when the recording knows it (CARMEN)


def read_odometry(path: str, topic: str) -> list[tuple[float, Rigid2D]]:
    """(stamp, base pose) of each of the nav_msgs/Odometry messages on `topic`, by header stamp."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore
    try:
        reader = Reader(path)
        reader.open()
    except Exception as e:      # rosbags raises several types for a missing or malformed recording
        raise BagError(f'{path}: not a readable rosbag2 recording ({type(e).__name__}: {e})') from None
    try:
        connections = [c for c in reader.connections if c.topic == topic]
        if not connections or any(c.msgtype != ODOMETRY for c in connections):
            found = ', '.join(sorted({f'{c.topic} ({c.msgtype})' for c in reader.connections})) or 'none'
            raise BagError(f'{path}: no {ODOMETRY} on {topic} (--odom-topic); the recording has: {found}')
        typestore = get_typestore(Stores.ROS2_JAZZY)
        poses = []
        for connection, _, raw in reader.messages(connections=connections):
            msg = typestore.deserialize_cdr(raw, connection.msgtype)
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
            poses.append((msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec, Rigid2D(p.x, p.y, yaw)))
    finally:
        reader.close()
    return sorted(poses, key=lambda stamped: stamped[0])


def bag_frames(path: str, scan_topic: str, odom_topic: str) -> list[Frame]:
    """Every LaserScan of the recording with the odometry interpolated at its stamp (None
    outside the odometry's span: a pose there would be a guess)."""
    from .bagfile import read_scans
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
    from .bench.carmen import read_flaser
    return [Frame(i, r.scan, r.odometry, r.pose) for i, r in enumerate(read_flaser(path))]


def observations(frames: list[Frame], start: int, follow_s: float, end: Optional[int] = None):
    """The frames after `start` (up to `end`) within follow_s of its stamp, as observations;
    unusable scans and scans without odometry skipped (the odometry spans the gap)."""
    t0 = frames[start].scan.stamp
    for frame in frames[start + 1:end]:
        if frame.scan.stamp - t0 > follow_s:
            return
        if frame.odometry is None:
            continue
        try:
            points = scan_to_points(frame.scan)
        except ScanError:
            continue
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


def follow_start(localizer, frames: list[Frame], start: int, follow_s: float, base_T_laser: Rigid2D,
                 method: Optional[str] = None, end: Optional[int] = None) -> dict:
    """One start scan localized and, when ambiguous, followed: its output line as a dict."""
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
        follower.follow(observations(frames, start, follow_s, end))
        outcome = follower.finish()
        final, settled = outcome.result, outcome.settled
        at = frame if outcome.last is None else outcome.last.source
        moved = {'distance_m': round(outcome.travelled_m, 3), 'turn_deg': round(math.degrees(outcome.turned_rad), 1),
                 'scans': outcome.scans, 'follow_s': round(outcome.elapsed_s, 3)}
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
    from .bench.carmen import LogGrid, read_flaser
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
    for start in start_indices(frames, args.every):
        row = follow_start(localizer, frames, start, args.follow_s, base_T_laser or Rigid2D(), args.method)
        print(json.dumps({'method': method, **row}), flush=True)
    return 0
