"""Real laser logs in the CARMEN format (Radish data sets) and the occupancy maps built
from them (no ROS): `localize --carmen` and the benchmark read them here.

FLASER n r1..rn x y theta odom_x odom_y odom_theta ipc_timestamp hostname logger_timestamp:
beams from -pi/2 counter-clockwise (1 deg for 180/181 beams, 0.5 deg for 360/361),
`x y theta` the SLAM-corrected laser pose, a reading within 1% of the log's maximum
value meaning "no return". The FLASER odom fields equal the corrected pose in these logs
(the truth); the raw odometry is in the ODOM records (`ODOM x y theta tv rv accel ...`):
the one after a FLASER repeats its corrected pose, later ones move that pose by the raw
odometry, so the raw motion from scan k-1 to scan k is corrected[k-1]^-1 * (the last ODOM
pose before FLASER k).
"""
from __future__ import annotations

import gzip
import logging
import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..core.grid_frame import GridFrame
from ..core.map_io import FREE, OCCUPIED, UNKNOWN, OccupancyMap, make_map
from ..core.scan import Scan, polar_to_points
from ..core.transform import Rigid2D

LOG = logging.getLogger(__name__)


@dataclass
class LaserRecord:
    scan: Scan
    pose: Rigid2D          # corrected laser pose
    timestamp: float
    odometry: Rigid2D = field(default_factory=Rigid2D)   # laser pose by the raw odometry alone (its own frame)
    line: int = 0          # its line in the log file, from 1


def read_flaser(path: str) -> list[LaserRecord]:
    """All FLASER records of a (gzipped) CARMEN log, in file order, each with its raw odometry.
    A record that cannot be read (a last line cut mid-write, 0 beams, a field not a number)
    is skipped with a warning naming its line: the rest of the log is still a log."""
    opener = gzip.open if path.endswith('.gz') else open
    raw, odom = [], None            # odom: the last ODOM pose read
    with opener(path, 'rt') as f:
        for number, line in enumerate(f, 1):
            if not line.startswith(('ODOM ', 'FLASER ')):
                continue
            try:
                if line.startswith('ODOM '):
                    odom = _odom_pose(line)
                    continue
                ranges, pose, stamp = _flaser_fields(line)
            except ValueError as e:
                LOG.warning('%s line %d: %s record skipped: %s', path, number, line.split()[0], e)
                continue
            raw.append((ranges, pose, stamp, odom, number))
            odom = None
    if not raw:
        raise ValueError(f'{path}: no FLASER records')
    max_reading = max(float(r[0].max()) for r in raw)
    range_max = 0.99 * max_reading            # at or above: no return (dropped by scan_to_points)
    records = []
    for ranges, pose, stamp, odom, number in raw:
        n = len(ranges)
        increment = math.radians(1.0) if n <= 181 else math.radians(0.5)
        odometry = Rigid2D()
        if records:     # no ODOM since the last scan: no motion measured
            previous = records[-1]
            odometry = previous.odometry * (previous.pose.inverse() * odom if odom is not None else Rigid2D())
        records.append(LaserRecord(Scan(-math.pi / 2, increment, 0.0, range_max, ranges, stamp), pose, stamp,
                                   odometry, number))
    return records


def _odom_pose(line: str) -> Rigid2D:
    values = line.split()[1:4]
    if len(values) < 3:
        raise ValueError('fewer than 3 values (a line cut short?)')
    return Rigid2D(*_finite(values))


def _flaser_fields(line: str) -> tuple[np.ndarray, Rigid2D, float]:
    """(ranges, corrected laser pose, timestamp) of a FLASER line; ValueError saying why not."""
    parts = line.split()
    n = int(parts[1]) if len(parts) > 1 else 0
    if n < 1:
        raise ValueError(f'{n} beams')
    if len(parts) < 9 + n:
        raise ValueError(f'{len(parts)} fields, {9 + n} needed for {n} beams (a line cut short?)')
    ranges = np.array(_finite(parts[2:2 + n]))
    x, y, theta = _finite(parts[2 + n:5 + n])
    return ranges, Rigid2D(x, y, theta), float(_finite(parts[8 + n:9 + n])[0])


def _finite(values) -> list[float]:
    numbers = [float(v) for v in values]
    if not all(map(math.isfinite, numbers)):
        raise ValueError('a value that is not a finite number')
    return numbers


@dataclass
class GridCounts:
    """Per-cell counts from a set of scans over a fixed grid: beam end points (`hits`)
    and scans whose swept area covers the cell (`visits`). Counts add, so a map from
    all folds but one is a sum."""
    hits: np.ndarray
    visits: np.ndarray

    def __add__(self, other: 'GridCounts') -> 'GridCounts':
        return GridCounts(self.hits + other.hits, self.visits + other.visits)


class LogGrid:
    """The common grid of a log's maps (bounds from all poses and end points, + margin)
    and how scans are counted on it."""

    def __init__(self, records: list[LaserRecord], resolution: float, margin: float = 2.0, max_free: float = 15.0):
        pts = np.vstack([r.pose.apply(endpoints(r.scan)[0]) for r in records[::5]] +
                        [np.array([[r.pose.x, r.pose.y] for r in records])])
        lo, hi = pts.min(axis=0) - margin, pts.max(axis=0) + margin
        self.frame = GridFrame(resolution, int(math.ceil((hi[0] - lo[0]) / resolution)),
                               int(math.ceil((hi[1] - lo[1]) / resolution)), Rigid2D(float(lo[0]), float(lo[1]), 0.0))
        self.max_free = max_free

    def counts(self, records: list[LaserRecord]) -> GridCounts:
        f = self.frame
        hits = np.zeros((f.height, f.width), np.int32)
        visits = np.zeros((f.height, f.width), np.int32)
        for rec in records:
            points, no_return_points = endpoints(rec.scan, self.max_free)
            end = f.cell_of(rec.pose.apply(points))
            inside = f.contains(end)
            np.add.at(hits, (end[inside, 1], end[inside, 0]), 1)
            # The area a scan saw as free: the polygon laser -> beam ends (no-return beams
            # count as free out to max_free), filled in a window around the scan.
            poly = f.cell_of(np.vstack([[rec.pose.x, rec.pose.y], rec.pose.apply(no_return_points)]))
            c0, r0 = np.maximum(poly.min(axis=0), 0)
            c1, r1 = np.minimum(poly.max(axis=0) + 1, [f.width, f.height])
            if c1 <= c0 or r1 <= r0:
                continue
            window = np.zeros((r1 - r0, c1 - c0), np.uint8)
            cv2.fillPoly(window, [(poly - [c0, r0]).astype(np.int32)], 1)
            visits[r0:r1, c0:c1] += window
        return GridCounts(hits, visits)

    def occupancy_map(self, counts: GridCounts, source: str) -> OccupancyMap:
        """Occupied where a cell was hit at least twice and in at least a fifth of the
        scans that saw it (people walking by are hit once or twice among many visits);
        free where seen otherwise; unknown where never seen."""
        occ = np.full((self.frame.height, self.frame.width), UNKNOWN, np.int8)
        occ[counts.visits > 0] = FREE
        occupied = (counts.hits >= 2) & (counts.hits * 5 >= counts.visits)
        occ[occupied] = OCCUPIED
        return make_map(occ, self.frame.resolution, self.frame.origin, source)


def endpoints(scan: Scan, max_free: float = 15.0):
    """(valid end points, polygon points with no-return and long beams capped at max_free),
    both in the laser frame."""
    r = np.asarray(scan.ranges, dtype=float)
    a = scan.angles()
    valid = np.isfinite(r) & (r > scan.range_min) & (r < scan.range_max)
    capped = np.where(valid, np.minimum(r, max_free), max_free)
    return polar_to_points(r[valid], a[valid]), polar_to_points(capped, a)
