"""Command line: `python -m global_loc localize|simulate ...` (see --help).

`localize` reads JSON lines of LaserScan fields and writes one JSON line per scan, with
the typed outcome (`"outcome": "localized"`, ...). It is the stable interface outside
users drive the core with, without ROS.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys

import numpy as np

from ..core import limits
from ..core.limits import check_within
from ..core.localizer import Localizer, LocalizerConfig
from ..core.map_io import MapError, load_map_yaml
from ..core.map_set import MapSet, named_paths
from ..core.matchers import BranchAndBoundOptions, MethodError, method_names
from ..core.matchers.bnb import option_fields
from ..core.mount import LaserMount
from ..core.outcome import Outcome
from ..core.paths import default_map_yaml
from ..core.scan import Scan, ScanError, scan_to_points
from ..core.transform import Rigid2D, pose_error
from ..core.view import ViewConfig
from ..sim.laser import LaserConfig
from ..sim.raycast import sample_free_poses, simulate_scan


def json_line_scans(path: str):
    """(where, Scan or the ScanError, truth or None) per non-empty line of a JSON-lines file
    ('-': stdin). Bytes that are not UTF-8 make that line an error, not the run's end."""
    stream = sys.stdin.buffer if path == '-' else open(path, 'rb')
    with stream:
        for lineno, raw in enumerate(stream, 1):
            where = {'line': lineno}
            try:
                line = raw.decode('utf-8-sig' if lineno == 1 else 'utf-8')
                if not line.strip():
                    continue
                obj = json.loads(line)
                if not isinstance(obj, dict):
                    raise ScanError('expected a JSON object with LaserScan fields')
                yield where, Scan.from_dict(obj), parse_truth(obj.get('truth'))
            except (UnicodeDecodeError, json.JSONDecodeError, ScanError) as e:
                yield where, ScanError(f'line {lineno}: {e}'), None


def parse_truth(value) -> Rigid2D | None:
    """A line's optional "truth": {"x": m, "y": m, "yaw": rad}, finite numbers; ScanError otherwise."""
    if value is None:
        return None
    try:
        if not isinstance(value, dict) or any(isinstance(value.get(k), bool) for k in ('x', 'y', 'yaw')):
            raise TypeError
        x, y, yaw = (float(value[k]) for k in ('x', 'y', 'yaw'))
    except (KeyError, TypeError, ValueError):
        raise ScanError(f'"truth" must be {{"x": m, "y": m, "yaw": rad}} with numbers, got {json.dumps(value)[:80]}') \
            from None
    if not all(map(math.isfinite, (x, y, yaw))):
        raise ScanError(f'"truth" must be finite, got {json.dumps(value)[:80]}')
    return Rigid2D(x, y, yaw)


def bag_scans(path: str, topic: str, every: int, mounting: dict | None = None, mount: LaserMount | None = None):
    """(where, Scan, None) per LaserScan of a rosbag2 recording, turned upright when `mount`
    is upside down; `where` carries `mounting` (where the laser's mounting came from) when given."""
    from ..io.bag import read_scans
    for index, scan in read_scans(path, topic, every):
        yield {'index': index, 'stamp': round(scan.stamp, 9), **({'mounting': mounting} if mounting else {})}, \
            mount.upright(scan) if mount else scan, None


def laser_mounting(args) -> tuple[LaserMount, dict]:
    """The laser's pose on the robot base, so the printed poses are the base's, as the server
    publishes them: with --bag from the recording's /tf_static (and the /tf transforms that
    never change) when they have it, else the --laser-x/--laser-y/--laser-yaw flags; and what
    a line says of where it came from. The flags have the server's laser_* ranges (ValueError)."""
    for axis, bounds in (('x', limits.LASER_OFFSET_M), ('y', limits.LASER_OFFSET_M), ('yaw', limits.LASER_ANGLE_RAD)):
        value = getattr(args, f'laser_{axis}')
        if value is not None:
            check_within(f'--laser-{axis}', value, bounds)
    flags = LaserMount(Rigid2D(args.laser_x or 0.0, args.laser_y or 0.0, args.laser_yaw or 0.0))
    said = {'from': '--laser-x/--laser-y/--laser-yaw', **flags.base_T_laser.as_dict()}
    if not args.bag:
        return flags, said
    from ..io.bag import MountingNotFound, read_mounting
    try:
        found = read_mounting(args.bag, args.topic, args.base_frame)
    except MountingNotFound as e:
        return flags, {**said, 'because': f'the bag has no mounting of the laser on {args.base_frame}: {e}'}
    if any(v is not None for v in (args.laser_x, args.laser_y, args.laser_yaw)):
        print(f'note: the laser mounting comes from the bag ({found.source}: {found.chain}); '
              f'--laser-x/--laser-y/--laser-yaw are not used', file=sys.stderr)
    return found.mount, {'from': found.source, 'frames': found.chain, **found.base_T_laser.as_dict(),
                         **({'upside_down': True} if found.mount.upside_down else {})}


def result_fields(result) -> dict:
    """A localization's fields of its output line (the pose, the outcome, what bnb's search did)."""
    out = {} if result.pose is None else result.pose.as_dict()
    out.update(outcome=result.outcome.label, score=round(result.score, 5) if math.isfinite(result.score) else None,
               success=result.success, confidence=round(result.confidence, 4),
               time_s=round(result.time_s, 4), message=result.message,
               hypotheses=[{**h.pose.as_dict(), 'score': round(h.score, 5), **({'map': h.map} if h.map else {})}
                           for h in result.hypotheses])
    if result.raw is not None:       # a thesis matcher's own verdict, before the map check
        raw = result.raw
        out['raw'] = {'outcome': raw.outcome.label, 'success': raw.success, 'confidence': round(raw.confidence, 4),
                      **(raw.pose.as_dict() if raw.pose is not None else {})}
    stats = result.search_stats
    if getattr(stats, 'search_s', None) is not None:     # bnb: what its search did, to tell why one was slow
        out['search'] = {'expansions': stats.expansions, 'headings': stats.angles, 'points': stats.points,
                         'search_s': round(stats.search_s, 4), 'exact': stats.exact}
    return out


def several_sensors(args) -> bool:
    """Whether the command line merges several sensors (more than one --topic, or a --cloud-topic)."""
    args.topic = args.topic or ([] if args.cloud_topic else ['/scan'])
    several = len(args.topic) > 1 or bool(args.cloud_topic) or bool(args.mount)
    if (several or args.merge_window is not None) and not args.bag:
        raise ValueError('several --topic values, --cloud-topic, --mount and --merge-window read a --bag')
    if several and (args.follow or args.plot):
        raise ValueError('--follow and --plot take one laser: a single --topic without --cloud-topic or --mount')
    if args.merge_window is None:
        args.merge_window = ViewConfig.merge_window_s
    if not several:
        args.topic = args.topic[0]
    return several


def named_maps(args) -> dict:
    """The maps to localize in, by name: each --map (PATH, named by its file, or NAME=PATH),
    the shipped office map without one, and with --carmen and no --map the log's own map."""
    if args.carmen and not args.map:
        from .follow import carmen_map
        return {os.path.basename(args.carmen): carmen_map(args.carmen)}
    return {name: load_map_yaml(path) for name, path in named_paths(args.map or [default_map_yaml()]).items()}


def localize_main(args) -> int:
    several = several_sensors(args)
    maps = named_maps(args)
    if len(maps) > 1 and (several or args.follow or args.carmen or args.plot):
        raise ValueError('--follow, --plot, --carmen and several sensors take one --map')
    bnb = BranchAndBoundOptions(**{name: getattr(args, f'bnb_{name}') for name, *_ in option_fields()})
    mount, mounting = (LaserMount(Rigid2D()), None) if several else laser_mounting(args)
    base_T_laser = mount.base_T_laser
    config = LocalizerConfig(method=args.method, angle_step_deg=args.angle_step, closing_kernel=args.closing_kernel,
                             bnb=bnb, max_search_s=args.max_search_s, base_T_laser=base_T_laser,
                             verify=not args.no_verify)
    localizers = {name: Localizer(m, config) for name, m in maps.items()}
    localizer = next(iter(localizers.values()))
    method = localizer.matcher(args.method).name   # unknown method: fail before reading any scan
    if several:
        from .views import localize_views
        return localize_views(args, localizer, method, result_fields)
    if args.follow:
        if mount.upside_down:
            raise ValueError("--follow: the bag's tf mounts the laser upside down; only --bag without --follow "
                             'turns its scans upright')
        from .follow import follow_main
        return follow_main(args, localizer, base_T_laser)
    if args.carmen:
        from .follow import carmen_scans
        scans = carmen_scans(args.carmen, args.every)
    elif args.bag:
        scans = bag_scans(args.bag, args.topic, args.every, mounting, mount)
    else:
        scans = json_line_scans(args.scans)
    return localize_scans(args, MapSet(localizers) if len(localizers) > 1 else localizer, scans,
                          {'method': method, 'map': next(iter(maps))})


def localize_scans(args, localizer, scans, fields: dict) -> int:
    """One output line per scan: `fields` (the method; the map, which a map set's answer names
    itself), then the result's."""
    for n, (where, scan, truth) in enumerate(scans, 1):
        out = {**where, **fields}
        try:
            if isinstance(scan, ScanError):
                raise scan
            result = localizer.localize(scan)
        except ScanError as e:
            print(json.dumps({**out, 'outcome': Outcome.UNUSABLE_SCAN.label, 'error': str(e)}), flush=True)
            continue
        out.update(result_fields(result))
        if isinstance(localizer, MapSet):
            out['map'] = result.map or None        # no pose on any map: none named
        if truth is not None and result.pose is not None:
            d, a = pose_error(result.pose, truth)
            out.update(truth=truth.as_dict(), error_xy=round(d, 4), error_yaw_deg=round(a, 3))
        print(json.dumps(out), flush=True)
        if args.plot:
            stem, ext = os.path.splitext(args.plot)
            path = args.plot if n == 1 else f'{stem}_{n:03d}{ext or ".png"}'
            from .plot import DrawnPoses, plot_localization
            plot_localization(path, localizer.map, scan_to_points(scan).points,
                              DrawnPoses(result.pose, truth, result.hypotheses),
                              title=f'{fields["method"]}: {result.message}')
    return 0


def simulate_main(args) -> int:
    """Ray-cast scans from seeded random free poses; each line carries its 'truth'."""
    occupancy_map = load_map_yaml(args.map)
    rng = np.random.default_rng(args.seed)
    beams = args.beams or int(round(args.fov / 0.5)) + (0 if args.fov >= 360 else 1)
    laser = LaserConfig(args.fov, beams, range_max=args.range, noise_std=args.noise, dropout=args.dropout)
    for pose in sample_free_poses(occupancy_map, args.count, rng):
        scan = simulate_scan(occupancy_map, pose, laser, rng=rng)
        print(json.dumps({**scan.to_dict(), 'truth': pose.as_dict()}))
    return 0


def add_sensor_arguments(loc: argparse.ArgumentParser) -> None:
    """--bag's sensors: the topics, and for several, their mountings and the merge window."""
    loc.add_argument('--topic', action='append', help='with --bag: a LaserScan topic (default /scan); given again, '
                                                       'the lasers are merged into one view as the server does, '
                                                       'for each message of the first')
    loc.add_argument('--cloud-topic', action='append', help='with --bag: a PointCloud2 topic merged into the view')
    loc.add_argument('--mount', nargs=7, action='append', metavar=('TOPIC', 'X', 'Y', 'Z', 'ROLL', 'PITCH', 'YAW'),
                     help="with --bag: a sensor's mounting on the base (m, rad) when the bag's tf does not have "
                          'its frame')
    loc.add_argument('--merge-window', type=float, default=None,
                     help='with several sensors: a sensor whose newest message is older than the newest one by '
                          f'more, s, is left out (default {ViewConfig.merge_window_s})')


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='python -m global_loc', description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest='command', required=True)
    loc = sub.add_parser('localize', help='localize scans (JSON lines) in a map')
    loc.add_argument('--map', action='append',
                     help='nav2 map YAML (default: the shipped office map; with --carmen, a map built from the log '
                          'at its corrected poses). Several --map: a map set (floors, sites) - each scan is '
                          'searched on every map and the answer names its map (NAME=PATH names one; by default its '
                          "file's name without .yaml); identical places on two maps are ambiguous")
    source = loc.add_mutually_exclusive_group(required=True)
    source.add_argument('--scans', help="JSON-lines file of LaserScan fields, or '-' for stdin")
    source.add_argument('--bag', help='rosbag2 recording (directory; sqlite3 or mcap) to read LaserScans from')
    source.add_argument('--carmen', help='CARMEN log (.log or .log.gz): its FLASER scans, truth from the corrected '
                                         'poses, odometry from the ODOM lines')
    add_sensor_arguments(loc)
    loc.add_argument('--base-frame', default='base_link',
                     help="with --bag: the robot base's frame; the laser's mounting on it is read from the bag's "
                          '/tf_static and fixed /tf transforms (default base_link)')
    for axis, unit in (('x', 'm'), ('y', 'm'), ('yaw', 'rad')):
        loc.add_argument(f'--laser-{axis}', type=float, default=None,
                         help=f'laser mounting on the robot base, {unit} (default 0; with --bag: used only when the '
                              f'bag has no transform to the laser frame)')
    loc.add_argument('--every', type=int, default=1, help='with --bag or --carmen: localize every N-th scan '
                                                          '(default 1; with --follow: start at every N-th)')
    loc.add_argument('--follow', action='store_true',
                     help='with --bag or --carmen: when a start scan is ambiguous, follow its hypotheses over the '
                          'next scans with the recorded odometry, as the server resolves by motion')
    loc.add_argument('--follow-s', type=float, default=30.0,
                     help='with --follow: seconds of recording to follow for at most (default 30), and at most '
                          '1 m/s x that far and 40 Hz x that many scans (stamps may repeat)')
    loc.add_argument('--odom-topic', default='/odom', help='with --bag --follow, or several sensors: the '
                                                           'nav_msgs/Odometry topic (several sensors: used when '
                                                           'present, to move each reading to the view\'s stamp)')
    loc.add_argument('--method', default=LocalizerConfig.method, help=f'one of: {", ".join(method_names())}')
    loc.add_argument('--no-verify', action='store_true',
                     help="thesis matchers: their own verdict, as the thesis reported it, without bnb's map check "
                          '(the server always checks); each line carries the raw verdict as "raw" either way')
    loc.add_argument('--angle-step', type=float, default=LocalizerConfig.angle_step_deg, help='Δα, degrees')
    loc.add_argument('--max-search-s', type=float, default=math.inf,
                     help='seconds a search may take, then "search incomplete" (default: no limit)')
    loc.add_argument('--closing-kernel', '--opening-kernel', dest='closing_kernel', type=int,
                     default=LocalizerConfig.closing_kernel,
                     help='kernel of the morphological closing of the local map\'s obstacles, pixels (0 = off); '
                          '--opening-kernel, the thesis\'s name and the ROS parameter\'s, is the same flag')
    loc.add_argument('--plot', help='save a picture per scan (OUT.png, OUT_002.png, ...)')
    for name, kind, default, help_text in option_fields():
        loc.add_argument(f'--bnb-{name.replace("_", "-")}', dest=f'bnb_{name}', type=kind, default=default,
                         help=f'bnb: {help_text} (default {default:g})'.replace('%', '%%'))   # argparse formats help
    loc.set_defaults(func=localize_main)
    sim = sub.add_parser('simulate', help='ray-cast scans from random free poses (with their truth)')
    sim.add_argument('--map', default=default_map_yaml())
    sim.add_argument('--count', type=int, default=20)
    sim.add_argument('--seed', type=int, default=0)
    sim.add_argument('--fov', type=float, default=270.0, help='field of view, degrees')
    sim.add_argument('--beams', type=int, default=0, help='beam count (default: one per 0.5 deg)')
    sim.add_argument('--range', type=float, default=20.0, help='max range, m')
    sim.add_argument('--noise', type=float, default=0.01, help='range noise std, m')
    sim.add_argument('--dropout', type=float, default=0.02, help='fraction of beams with no return')
    sim.set_defaults(func=simulate_main)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (MapError, MethodError, OSError, ValueError) as e:
        print(f'error: {e}', file=sys.stderr)
        return 2
