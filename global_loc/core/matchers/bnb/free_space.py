"""The free-space check of bnb's hypotheses. The likelihood field only rewards end
points, so a pose whose beams pass through mapped walls to reach them (a corridor
matched 180 deg reversed, a twin room behind a closed door) can score as high as the
truth. Each refined hypothesis is therefore checked ray by ray: the fraction of the
scan's beams, returns and no-returns, that cross an occupied cell before their end.
"""
from __future__ import annotations

import numpy as np

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
