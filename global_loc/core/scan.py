"""Laser scans: the LaserScan fields as a plain type, validated and turned into points.

`Scan` carries exactly the sensor_msgs/LaserScan fields the method needs, so the ROS
node, the CLI (JSON lines), the simulator and the log readers all build the same object,
and `scan_to_points` is the one place that decides which readings count.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

MIN_POINT_SEPARATION_M = 0.01     # points closer than this count as one (a 1 cm grid)


class ScanError(ValueError):
    """A scan cannot be used (malformed fields, or no valid reading at all)."""


@dataclass
class Scan:
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: np.ndarray
    stamp: float = 0.0      # seconds; the ROS node keeps the message stamp itself
    # The LaserScan's angle_max, checked against angle_min + (n - 1) x angle_increment (a
    # filter that flipped one field mirrors the scan); None: not known (CARMEN logs, JSON
    # lines without it).
    angle_max: Optional[float] = None

    @staticmethod
    def from_dict(d: dict) -> 'Scan':
        """From a JSON object with LaserScan field names; a no-return reading may be null."""
        missing = [k for k in ('angle_min', 'angle_increment', 'range_min', 'range_max', 'ranges') if k not in d]
        if missing:
            raise ScanError(f'scan is missing field(s): {", ".join(missing)}')
        try:
            ranges = np.array([np.nan if r is None else r for r in d['ranges']], dtype=float)
            angle_max = d.get('angle_max')
            return Scan(float(d['angle_min']), float(d['angle_increment']), float(d['range_min']),
                        float(d['range_max']), ranges, float(d.get('stamp', 0.0)),
                        None if angle_max is None else float(angle_max))
        except (TypeError, ValueError) as e:
            raise ScanError(f'scan has a non-numeric field: {e}') from None

    def angles(self) -> np.ndarray:
        """Each beam's angle in the laser frame (counter-clockwise from x)."""
        return self.angle_min + self.angle_increment * np.arange(np.asarray(self.ranges).size)

    def to_dict(self) -> dict:
        out = {'angle_min': self.angle_min, 'angle_increment': self.angle_increment,
               'range_min': self.range_min, 'range_max': self.range_max,
               'ranges': [None if not math.isfinite(r) else round(float(r), 4) for r in self.ranges]}
        if self.angle_max is not None:
            out['angle_max'] = self.angle_max
        return out


@dataclass
class ScanPoints:
    """Valid returns of one scan as points in the laser frame (x forward, y left)."""
    points: np.ndarray                      # (N, 2) metres
    range_max: float
    num_beams: int
    dropped: dict = field(default_factory=dict)   # reason -> count of readings dropped
    # Laser-frame angles of beams that saw nothing within range_max (+inf, or a reading at
    # range_max): evidence that the space along them is free, which a match can contradict.
    no_return_angles: np.ndarray = field(default_factory=lambda: np.empty(0))
    # False for points that are not beam end points (a local map cut from the map: its
    # walls need not be visible from the centre), so nothing can be said about free space.
    beams: bool = True


def scan_to_points(scan: Scan) -> ScanPoints:
    """Drop NaN, +-inf and out-of-[range_min, range_max] readings (counted per reason);
    raise ScanError on malformed fields or when nothing valid is left."""
    for name in ('angle_min', 'angle_increment', 'range_min', 'range_max'):
        if not math.isfinite(getattr(scan, name)):
            raise ScanError(f'scan field {name} is not finite: {getattr(scan, name)}')
    if scan.angle_increment == 0:
        raise ScanError('scan angle_increment is 0')
    if not (0 <= scan.range_min < scan.range_max):
        raise ScanError(f'need 0 <= range_min < range_max, got {scan.range_min}, {scan.range_max}')
    ranges = np.asarray(scan.ranges, dtype=float).ravel()
    if ranges.size == 0:
        raise ScanError('scan has no readings')
    with np.errstate(over='ignore', invalid='ignore'):
        angles = scan.angles()
    if not np.isfinite(angles).all():
        raise ScanError(f'beam angles overflow: angle_min {scan.angle_min} + i x angle_increment '
                        f'{scan.angle_increment} is not finite for every beam')
    check_angle_max(scan, float(angles[-1]))
    nan = np.isnan(ranges)
    inf = np.isinf(ranges)
    finite = ~(nan | inf)
    low = finite & (ranges < scan.range_min)
    # A reading at range_max is the usual "no return" (CARMEN, many drivers): drop it too.
    high = finite & (ranges >= scan.range_max)
    ok = finite & ~low & ~high
    dropped = {'nan': int(nan.sum()), 'inf': int(inf.sum()),
               'below_range_min': int(low.sum()), 'at_or_above_range_max': int(high.sum())}
    if not ok.any():
        raise ScanError(f'scan has no valid reading among {ranges.size} '
                        f'(dropped: {", ".join(f"{k}={v}" for k, v in dropped.items() if v)})')
    pts = polar_to_points(ranges[ok], angles[ok])
    # -inf is "too close to measure" (REP 117), NaN unknown: neither says the beam's path is free.
    no_return = (inf & (ranges > 0)) | high
    return ScanPoints(pts, float(scan.range_max), int(ranges.size), dropped, angles[no_return])


def check_angle_max(scan: Scan, last_angle: float) -> None:
    """ScanError when the scan states an angle_max more than one increment away from its
    last beam's angle: the fields contradict each other (an increment whose sign was
    flipped gives a mirrored scan, confidently wrong), and which is right is unknown.
    One increment of slack: drivers differ on whether angle_max is the last beam's angle
    or one step past it."""
    if scan.angle_max is None:
        return
    if not math.isfinite(scan.angle_max):
        raise ScanError(f'scan field angle_max is not finite: {scan.angle_max}')
    off = abs(scan.angle_max - last_angle)
    if off > abs(scan.angle_increment) * (1 + 1e-6) + 1e-9:
        raise ScanError(f'scan angle_max {scan.angle_max:.6g} disagrees with angle_min + (n - 1) x angle_increment '
                        f'= {scan.angle_min:.6g} + {len(scan.ranges) - 1} x {scan.angle_increment:.6g} = '
                        f'{last_angle:.6g} by {off:.3g} rad, more than one increment: the fields contradict '
                        f'each other (a flipped angle_increment mirrors the scan)')


def count_distinct_up_to_3(rows: np.ndarray) -> int:
    """How many distinct rows `rows` holds, counted up to 3 (a full np.unique sorts every
    row of a 1 000-beam scan: ~10x the time, for a check that needs three)."""
    if len(rows) == 0:
        return 0
    off_first = (rows != rows[0]).any(axis=1)
    if not off_first.any():
        return 1
    second = rows[np.argmax(off_first)]
    return 3 if (off_first & (rows != second).any(axis=1)).any() else 2


def require_shape(points: ScanPoints) -> ScanPoints:
    """ScanError unless the points hold at least 3 distinct places (1 cm apart): fewer
    have no shape to match, and every pose would fit them equally well."""
    distinct_points = count_distinct_up_to_3(np.round(points.points / MIN_POINT_SEPARATION_M))
    if distinct_points < 3:
        raise ScanError(f'scan has {distinct_points} distinct point(s) ({len(points.points)} valid readings): at '
                        f'least 3 are needed to match a shape')
    return points


def polar_to_points(ranges: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(N, 2) laser-frame points of beams of `ranges` at `angles`."""
    return np.stack([ranges * np.cos(angles), ranges * np.sin(angles)], axis=1)


def voxel_filter(points: np.ndarray, size: float) -> np.ndarray:
    """The first point (in order) of each size x size cell; all of them when size is 0.
    Cells are floor(p / size): bnb keeps one point per map cell with it, and a view
    filtered at the map's resolution gives bnb exactly the points it would keep."""
    if size <= 0 or len(points) == 0:
        return points
    keys = np.floor(points / size).astype(np.int64)
    keys -= keys.min(axis=0)
    _, first = np.unique(keys[:, 0] * (int(keys[:, 1].max()) + 1) + keys[:, 1], return_index=True)
    return points[np.sort(first)]
