"""A numpy 2-D ray caster over an OccupancyMap: scans for tests, the CLI's `simulate`,
and the benchmark. It sees exactly the map's occupied cells; the pybullet simulator
(global_loc/sim) is the one that adds a robot body, clutter and a laser rate."""
from __future__ import annotations

import math

import numpy as np

from .map_io import OccupancyMap
from .scan import Scan, ScanPoints
from .transform import Rigid2D


def raycast_ranges(occupancy_map: OccupancyMap, laser_pose: Rigid2D, angles: np.ndarray,
                   range_max: float) -> np.ndarray:
    """Distance along each beam (laser-frame `angles`) to the first occupied cell;
    inf where nothing is hit within range_max. Marches at a quarter cell."""
    step = occupancy_map.resolution / 4.0
    t = np.arange(step, range_max + step, step)
    world_angles = laser_pose.yaw + np.asarray(angles, dtype=float)
    xs = laser_pose.x + np.cos(world_angles)[:, None] * t[None, :]
    ys = laser_pose.y + np.sin(world_angles)[:, None] * t[None, :]
    uv = occupancy_map.world_to_pixel(np.stack([xs.ravel(), ys.ravel()], axis=1))
    col = np.rint(uv[:, 0]).astype(int)
    row = np.rint(uv[:, 1]).astype(int)
    inside = (col >= 0) & (col < occupancy_map.width) & (row >= 0) & (row < occupancy_map.height)
    hit = np.zeros(col.shape, dtype=bool)
    hit[inside] = occupancy_map.occupied[row[inside], col[inside]]
    hit = hit.reshape(xs.shape)
    first = np.argmax(hit, axis=1)
    ranges = np.where(hit.any(axis=1), t[first], np.inf)
    return np.where(ranges <= range_max, ranges, np.inf)


def simulate_scan(occupancy_map: OccupancyMap, laser_pose: Rigid2D, fov_deg: float = 270.0,
                  num_beams: int = 541, range_max: float = 20.0, range_min: float = 0.05,
                  noise_std: float = 0.0, dropout: float = 0.0, rng=None) -> Scan:
    """A LaserScan-like Scan centred on the laser's x axis; no-return beams are inf,
    dropouts NaN, Gaussian range noise `noise_std` metres."""
    rng = np.random.default_rng() if rng is None else rng
    fov = math.radians(fov_deg)
    full_circle = fov_deg >= 360.0
    increment = fov / num_beams if full_circle else fov / (num_beams - 1)
    angle_min = -math.pi if full_circle else -fov / 2.0
    angles = angle_min + increment * np.arange(num_beams)
    ranges = raycast_ranges(occupancy_map, laser_pose, angles, range_max)
    if noise_std > 0:
        ranges = ranges + rng.normal(0.0, noise_std, ranges.shape)
    if dropout > 0:
        ranges[rng.random(ranges.shape) < dropout] = np.nan
    return Scan(angle_min, increment, range_min, range_max, ranges)


def sample_free_poses(occupancy_map: OccupancyMap, n: int, rng, clearance: float = 0.4) -> list[Rigid2D]:
    """`n` poses on free cells at least `clearance` metres from any occupied or unknown
    cell, with uniform random headings."""
    import cv2
    known_free = occupancy_map.free.astype(np.uint8)
    dist = cv2.distanceTransform(known_free, cv2.DIST_L2, 5) * occupancy_map.resolution
    rows, cols = np.nonzero(dist >= clearance)
    if len(rows) == 0:
        raise ValueError(f'{occupancy_map.source}: no free cell with {clearance} m clearance')
    idx = rng.choice(len(rows), size=n, replace=len(rows) < n)
    xy = occupancy_map.pixel_to_world(np.stack([cols[idx], rows[idx]], axis=1).astype(float))
    yaws = rng.uniform(-math.pi, math.pi, n)
    return [Rigid2D(float(x), float(y), float(a)) for (x, y), a in zip(xy, yaws)]


def points_cut_from_map(occupancy_map: OccupancyMap, laser_pose: Rigid2D, radius: float) -> ScanPoints:
    """The map's wall-surface cells within `radius` of the pose, in the laser frame: the
    thesis's "local map cut from the global map" (§4.1), an upper bound for any matcher."""
    rows, cols = np.nonzero(occupancy_map.surface_image())
    xy = occupancy_map.pixel_to_world(np.stack([cols, rows], axis=1).astype(float))
    near = np.hypot(xy[:, 0] - laser_pose.x, xy[:, 1] - laser_pose.y) < radius
    return ScanPoints(laser_pose.inverse().apply(xy[near]), float(radius), int(near.sum()), beams=False)
