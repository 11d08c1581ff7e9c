"""The free-space check of bnb's hypotheses. The likelihood field only rewards end
points, so a pose whose beams pass through mapped walls to reach them (a corridor
matched 180 deg reversed, a twin room behind a closed door) can score as high as the
truth. Each refined hypothesis is therefore checked ray by ray: the fraction of the
scan's beams, returns and no-returns, that cross an occupied cell before their end.
"""
from __future__ import annotations

import numpy as np

from ...map_io import free_cells, occupied_cells
from ...pixel_kernels import first_hits
from ...scan import ScanPoints
from .options import BranchAndBoundOptions


def see_through_fractions(occupied: np.ndarray, poses: np.ndarray, points: ScanPoints, resolution: float,
                          options: BranchAndBoundOptions) -> np.ndarray:
    """Per pose (rows u, v, grid-frame yaw): the fraction of the scan's beams that would
    pass through an occupied cell - a return's beam up to see_through_tolerance_cells
    short of its end point, a no-return beam over its whole range (up to max_range).
    Zero for points that are not beams (a local map cut from the map)."""
    if len(poses) == 0 or not points.beams:
        return np.zeros(len(poses))
    ranges = np.hypot(points.points[:, 0], points.points[:, 1])
    near = ranges <= options.max_range
    angles = np.concatenate([np.arctan2(points.points[near, 1], points.points[near, 0]), points.no_return_angles])
    lengths = np.concatenate([ranges[near] / resolution - options.see_through_tolerance_cells,
                              np.full(len(points.no_return_angles),
                                      min(points.range_max, options.max_range) / resolution)])
    if len(angles) == 0:
        return np.zeros(len(poses))
    hits = first_hits(occupied, np.ascontiguousarray(poses, np.float64), angles.astype(np.float64),
                      lengths.astype(np.float64), 0.5)
    return np.isfinite(hits).sum(axis=1) / len(angles)


def clear_returns(occupied: np.ndarray, poses: np.ndarray, pts: np.ndarray, resolution: float,
                  options: BranchAndBoundOptions) -> np.ndarray:
    """(poses, points): whether each point's beam (laser frame, m) reaches it without
    crossing an occupied cell, up to see_through_tolerance_cells short of it, as
    see_through_fractions checks a return. A return on an unknown cell behind a mapped wall
    is contradicted by the map, not unknown to it."""
    if len(poses) == 0 or len(pts) == 0:
        return np.ones((len(poses), len(pts)), bool)
    lengths = np.hypot(pts[:, 0], pts[:, 1]) / resolution - options.see_through_tolerance_cells
    hits = first_hits(occupied, np.ascontiguousarray(poses, np.float64), np.arctan2(pts[:, 1], pts[:, 0]),
                      lengths.astype(np.float64), 0.5)
    return ~np.isfinite(hits)


def on_unknown(occupancy: np.ndarray, poses: np.ndarray, pts: np.ndarray, resolution: float) -> np.ndarray:
    """(poses, points): whether each point (laser frame, m) lands on a cell the map says
    nothing about (neither free nor occupied, as OccupancyMap has them) or off the map."""
    if len(poses) == 0 or len(pts) == 0:
        return np.zeros((len(poses), len(pts)), bool)
    px, py = pts[:, 0] / resolution, pts[:, 1] / resolution
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    x = np.rint(poses[:, 0][:, None] + c * px - s * py).astype(np.int64)     # pixel_kernels.image_point
    y = np.rint(poses[:, 1][:, None] - (s * px + c * py)).astype(np.int64)
    height, width = occupancy.shape
    inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
    cells = occupancy[np.where(inside, y, 0), np.where(inside, x, 0)]
    return ~(inside & (occupied_cells(cells) | free_cells(cells)))
