"""Several sensors merged into one view for the search: front and rear lasers, a 3D lidar.

A `SensorReading` is one sensor's newest points in its own frame with its 3D mounting on
the base. `merge_view` takes the newest reading of every sensor the robot has and keeps
those that arrived within `merge_window_s` of the newest one and whose clocks agree;
each is put in the base frame at its own stamp and moved by odometry to the reference
stamp (a rear scan 50 ms older then does not smear a turning robot), a 3D reading cut to
the height band that sees walls (not the floor, not the ceiling), all projected to the
floor and voxel-filtered once. What it returns is what every matcher takes: ScanPoints
with the frame they are in (`base_T_laser`), and which sensors contributed and which
were left out, and why.

One level 2D laser alone stays a scan: its points in the laser's upright frame, beams
from one origin, so bnb's free-space check still applies, and not voxel-filtered (bnb
filters what it searches itself, and refines and checks free space with every beam):
its answers are exactly those of the laser on its own. Anything merged is a view from the base origin whose points are
not beams from it (`beams=False`), as core.motion.fuse_scans has it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping, Optional, Union

import numpy as np

from .mount3d import Mount3D
from .pose_history import PoseHistory
from .scan import Scan, ScanError, ScanPoints, scan_to_points, voxel_filter
from .transform import Rigid2D

OdometryFn = Callable[[float], Optional[Rigid2D]]     # stamp -> base pose in the odometry frame


class ViewError(ScanError):
    """No view can be made: no sensor contributed (each one's reason is in the message),
    or a reading is malformed."""


@dataclass(frozen=True)
class ViewConfig:
    merge_window_s: float = 0.25     # a sensor whose newest reading arrived longer before the newest one is left out
    max_clock_offset_s: float = 1.0  # ... and one whose stamp is this much further off its arrival than the others'
    cloud_z_min: float = 0.2         # m above the floor (base frame): 3D points below are the floor ...
    cloud_z_max: float = 2.0         # ... and above it the ceiling; both left out
    voxel_size: float = 0.05         # m; one point per cell of the view (0: no filter)
    max_reach_m: float = 100.0       # farther points are left out (no indoor sensor sees that far; garbage)

    def __post_init__(self):
        for name in ('merge_window_s', 'max_clock_offset_s', 'voxel_size', 'max_reach_m'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f'view {name} must be finite and >= 0, got {value}')
        if not (math.isfinite(self.cloud_z_min) and math.isfinite(self.cloud_z_max)
                and self.cloud_z_min < self.cloud_z_max):
            raise ValueError(f'need finite cloud_z_min < cloud_z_max, got {self.cloud_z_min}, {self.cloud_z_max}')


@dataclass(frozen=True)
class SensorReading:
    sensor: str                      # its name (the topic)
    stamp: float                     # its header stamp, s
    points: np.ndarray               # (N, 2) in a 2D laser's scan plane, or (N, 3); sensor frame
    mount: Mount3D                   # the sensor's pose on the base
    range_max: float = math.inf      # the sensor's reach
    received: Optional[float] = None  # when it arrived (the receiver's clock); None: its stamp
    no_return_angles: np.ndarray = field(default_factory=lambda: np.empty(0))   # a 2D laser's empty beams
    num_beams: Optional[int] = None  # a 2D laser's beam count (None: the number of points)
    dropped: dict = field(default_factory=dict)    # reason -> readings the sensor's own parsing dropped

    @property
    def is_3d(self) -> bool:
        return self.points.shape[1] == 3

    @property
    def arrival(self) -> float:
        return self.stamp if self.received is None else self.received


def reading_from_scan(sensor: str, scan: Scan, mount: Mount3D, received: Optional[float] = None) -> SensorReading:
    """A 2D laser's reading (its valid returns, see scan_to_points; ScanError if none)."""
    points = scan_to_points(scan)
    return SensorReading(sensor, scan.stamp, points.points, mount, points.range_max, received,
                         points.no_return_angles, points.num_beams, points.dropped)


@dataclass
class View:
    points: ScanPoints               # what the matchers take, in the frame below
    base_T_laser: Rigid2D            # that frame on the base at `stamp` (identity: the base itself)
    stamp: float                     # the reference stamp every point was moved to
    contributed: dict                # sensor -> points it gave (before the voxel filter)
    left_out: dict                   # sensor -> why it is not in the view
    motion_compensated: bool = True  # False: no odometry, readings taken as if at `stamp`

    def summary(self) -> str:
        """One line for a result and /diagnostics: who contributed, who was left out, why."""
        used = ', '.join(f'{s} ({n} points)' for s, n in self.contributed.items())
        text = f'view from {used}; {len(self.points.points)} points after the voxel filter'
        if self.left_out:
            text += '; left out: ' + '; '.join(f'{s}: {why}' for s, why in self.left_out.items())
        if not self.motion_compensated:
            text += '; not motion-compensated (no odometry)'
        return text


def merge_view(readings: Mapping[str, Optional[SensorReading]],
               odometry: Union[PoseHistory, OdometryFn, None] = None,
               reference_stamp: Optional[float] = None, config: ViewConfig = ViewConfig(),
               unread: Optional[Mapping[str, str]] = None) -> View:
    """The view of every sensor in `readings` (sensor -> its newest reading, None: none
    yet) that can be merged, at `reference_stamp` (None: the newest contributing stamp).
    `odometry`: a PoseHistory or a stamp -> pose callable; None: the robot stood still.
    `unread`: sensors whose message gave no reading -> why (left out, said). Raises
    ViewError, saying every sensor's reason, when no sensor contributes a point."""
    left_out = dict(unread or {})
    left_out.update({name: 'silent: no reading received' for name, r in readings.items() if r is None})
    present = [check_reading(r) for r in readings.values() if r is not None]
    fresh = _leave_out_stale(present, config, left_out)
    fresh = _leave_out_clock_outliers(fresh, config, left_out)
    if reference_stamp is None and fresh:
        reference_stamp = max(r.stamp for r in fresh)
    lookup = odometry.at if isinstance(odometry, PoseHistory) else odometry
    reference_pose = lookup(reference_stamp) if lookup is not None and fresh else None
    prefix = len(readings) > 1
    dropped, parts, contributed = {}, [], {}
    for r in fresh:
        odom_at = lookup(r.stamp) if reference_pose is not None else None
        motion = reference_pose.inverse() * odom_at if odom_at is not None else Rigid2D()
        xyz, kept, drops = _points_in_band(r, config)
        drops = {**r.dropped, **{k: v for k, v in drops.items() if v}}
        dropped.update({(f'{r.sensor}.{k}' if prefix else k): v for k, v in drops.items()})
        if len(xyz) == 0:
            left_out[r.sensor] = 'no usable point (' + ', '.join(f'{k}={v}' for k, v in drops.items() if v) + ')'
            continue
        parts.append((r, motion, xyz, kept))
        contributed[r.sensor] = len(xyz)
    if not parts:
        reasons = '; '.join(f'{s}: {why}' for s, why in left_out.items()) or 'no sensor given'
        raise ViewError(f'no sensor contributed to the view ({reasons})')
    compensated = reference_pose is not None or all(p[0].stamp == reference_stamp for p in parts)
    if len(parts) == 1 and not parts[0][0].is_3d and parts[0][0].mount.is_level():
        points, base_T_laser = _laser_view(*parts[0])
    else:
        points, base_T_laser = _base_view(parts, config), Rigid2D()
    points.dropped = dropped
    return View(points, base_T_laser, float(reference_stamp), contributed, left_out, compensated)


def check_reading(r: SensorReading) -> SensorReading:
    """ViewError unless the reading's points are (N, 2) or (N, 3) numbers and its stamps finite."""
    pts = np.asarray(r.points)
    if pts.ndim != 2 or pts.shape[1] not in (2, 3) or not np.issubdtype(pts.dtype, np.number):
        raise ViewError(f'{r.sensor}: points must be an (N, 2) or (N, 3) array of numbers, got '
                        f'{pts.dtype} {pts.shape}')
    if not math.isfinite(r.stamp) or (r.received is not None and not math.isfinite(r.received)):
        raise ViewError(f'{r.sensor}: stamp {r.stamp} / arrival {r.received} is not finite')
    return r


def _leave_out_stale(readings: list, config: ViewConfig, left_out: dict) -> list:
    """The readings that arrived within merge_window_s of the newest one."""
    if not readings:
        return []
    newest = max(r.arrival for r in readings)
    kept = []
    for r in readings:
        age = newest - r.arrival
        if age > config.merge_window_s:
            left_out[r.sensor] = (f'too old: its newest reading arrived {age:.3f} s before the newest one '
                                  f'(merge_window_s {config.merge_window_s})')
        else:
            kept.append(r)
    return kept


def _leave_out_clock_outliers(readings: list, config: ViewConfig, left_out: dict) -> list:
    """The readings whose stamp is as far off their arrival as the others': the largest
    group of sensors whose clocks agree within max_clock_offset_s (ties: the one with the
    newest arrival). With no arrival times (offline) every offset is 0 and all agree."""
    if len(readings) < 2:
        return readings
    offsets = np.array([r.stamp - r.arrival for r in readings])
    agree = np.abs(offsets[:, None] - offsets[None, :]) <= config.max_clock_offset_s
    order = sorted(range(len(readings)), key=lambda i: (-agree[i].sum(), -readings[i].arrival))
    ref = order[0]
    kept = []
    for i, r in enumerate(readings):
        if agree[ref, i]:
            kept.append(r)
        else:
            left_out[r.sensor] = (f'clocks far apart: its stamp is {offsets[i] - offsets[ref]:+.3f} s off '
                                  f"{readings[ref].sensor}'s for messages that arrived together "
                                  f'(max_clock_offset_s {config.max_clock_offset_s})')
    return kept


def _points_in_band(r: SensorReading, config: ViewConfig) -> tuple[np.ndarray, np.ndarray, dict]:
    """The reading's points in the base frame (N, 3) and the sensor frame: finite, within
    reach, and for a 3D reading or a tilted laser within the height band; with how many
    were dropped per reason."""
    pts = np.asarray(r.points, dtype=float)
    finite = np.isfinite(pts).all(axis=1)
    reach = np.full(len(pts), True)
    reach[finite] = np.linalg.norm(pts[finite], axis=1) <= config.max_reach_m
    kept = pts[finite & reach]
    xyz = r.mount.apply(kept)
    drops = {'nan_or_inf': int((~finite).sum()), 'beyond_reach': int((finite & ~reach).sum())}
    if r.is_3d or not r.mount.is_level():      # a tilted 2D laser's far beams reach the floor too
        low, high = xyz[:, 2] < config.cloud_z_min, xyz[:, 2] > config.cloud_z_max
        drops.update(below_cloud_z_min=int(low.sum()), above_cloud_z_max=int(high.sum()))
        xyz, kept = xyz[~(low | high)], kept[~(low | high)]
    return xyz, kept, drops


def _laser_view(r: SensorReading, motion: Rigid2D, xyz: np.ndarray, kept: np.ndarray) -> tuple:
    """One level laser: its points in its upright frame (beams from its origin, whichever
    way up it is mounted; unfiltered, see above), that frame on the base at the reference
    stamp. Sensor frame -> upright frame is a 2x2 map, diag(1, +-1) for a laser mounted
    exactly upright or upside down: snapped to it, so such a laser's points are its own."""
    upright = r.mount.upright()
    to_upright = Rigid2D(0.0, 0.0, -upright.yaw).matrix()[:2, :2] @ r.mount.rotation()[:2, :2]
    snapped = np.round(to_upright)
    to_upright = np.where(np.abs(to_upright - snapped) < 1e-12, snapped, to_upright)
    angles = r.mount.base_angles(r.no_return_angles) - upright.yaw
    num_beams = r.num_beams if r.num_beams is not None else len(r.points)
    return ScanPoints(kept @ to_upright.T, float(r.range_max), num_beams, no_return_angles=angles), motion * upright


def _base_view(parts: list, config: ViewConfig) -> ScanPoints:
    """Every part's points moved to the base at the reference stamp, filtered, and ordered
    by bearing (bnb keeps an evenly spaced subset by index: then evenly around the robot)."""
    xy = np.vstack([motion.apply(xyz[:, :2]) for _, motion, xyz, _ in parts])
    xy = voxel_filter(xy, config.voxel_size)
    xy = xy[np.argsort(np.arctan2(xy[:, 1], xy[:, 0]), kind='stable')]
    reach = float(np.hypot(xy[:, 0], xy[:, 1]).max(initial=0.0))
    sensor_reach = max(p[0].range_max for p in parts)
    range_max = max(reach, sensor_reach if math.isfinite(sensor_reach) else reach)
    return ScanPoints(xy, range_max, len(xy), beams=False)
