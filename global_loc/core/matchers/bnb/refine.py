"""From the search's leaves to refined peaks: the best leaf per bin, sub-cell refinement
on the interpolated likelihood field (Cartographer's CeresScanMatcher2D does this step
with Ceres; here Nelder-Mead within a cell), and the covariance from the score landscape
around the chosen peak. Poses here are (u, v, yaw): pixel position and grid-frame heading.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit
from scipy.optimize import minimize

from ...grid_frame import GridFrame
from ...pixel_kernels import image_point

# The field's unit: grids.PrecomputationGridStack keeps it as the search's leaves read it,
# uint8 rint(255 x likelihood)
FIELD_UNIT = 1.0 / 255.0


@njit(cache=True, nogil=True, inline='always')
def bilinear(field, x, y):
    """The field (uint8, in FIELD_UNIT) bilinearly interpolated at pixel (x, y), zero outside it."""
    height, width = field.shape
    x0, y0 = math.floor(x), math.floor(y)
    fx, fy = x - x0, y - y0
    ix, iy = int(x0), int(y0)
    total = 0.0
    for dy in range(2):
        for dx in range(2):
            xx, yy = ix + dx, iy + dy
            if 0 <= xx < width and 0 <= yy < height:
                total += field[yy, xx] * (fx if dx else 1.0 - fx) * (fy if dy else 1.0 - fy)
    return total * FIELD_UNIT


@njit(cache=True, nogil=True)
def field_means(field, poses, px, py):
    """Per pose (u, v, yaw): the mean of the field (uint8, in FIELD_UNIT), bilinearly
    interpolated (zero outside the map), at the points (px, py, laser frame, in cells)."""
    out = np.empty(poses.shape[0])
    for k in range(poses.shape[0]):
        c, s = math.cos(poses[k, 2]), math.sin(poses[k, 2])
        total = 0.0
        for i in range(len(px)):
            x, y = image_point(poses[k, 0], poses[k, 1], c, s, px[i], py[i])
            total += bilinear(field, x, y)
        out[k] = total / max(len(px), 1)
    return out


@njit(cache=True, nogil=True)
def field_samples(field, poses, px, py):
    """(poses, points): the field at each point, as field_means averages it."""
    out = np.empty((poses.shape[0], len(px)))
    for k in range(poses.shape[0]):
        c, s = math.cos(poses[k, 2]), math.sin(poses[k, 2])
        for i in range(len(px)):
            x, y = image_point(poses[k, 0], poses[k, 1], c, s, px[i], py[i])
            out[k, i] = bilinear(field, x, y)
    return out


class PeakBins(NamedTuple):
    """The bins a peak is the best of: distinct_cells^2 cells x distinct_angle rad."""
    cells: float
    angle: float


def bin_maxima(leaves: np.ndarray, scores: np.ndarray, d0: float, map_height: int, bins: PeakBins,
               limit: int = 512) -> np.ndarray:
    """Indices of the best leaf (rows u, v, angle index: the compiled search's columns) in
    each of the `bins`, the `limit` best of them, best first. The non-maximum suppression
    then sees a few hundred poses, not every leaf: a featureless view (a 60 deg glimpse of
    a straight wall) leaves a million poses within keep_ratio of the best."""
    tu, tv, ta = leaves[:, 0], leaves[:, 1], leaves[:, 2]
    distinct_cells, distinct_angle = bins
    cell = max(1, int(distinct_cells))
    a_bin = max(1, int(distinct_angle / d0))
    ku, kv, ka = tu // cell, tv // cell, ta // a_bin
    key = (ku * (map_height // cell + 1) + kv) * (int(ta.max(initial=0)) // a_bin + 1) + ka
    order = np.argsort(-scores, kind='stable')
    _, first = np.unique(key[order], return_index=True)
    best = order[first]
    return best[np.argsort(-scores[best], kind='stable')][:limit]


def one_cell_angle(pts: np.ndarray, resolution: float) -> float:
    """The turn (rad) that moves the scan's farthest point by one cell (at least a cell
    from the laser): the refinement's heading unit and the covariance's heading step."""
    return resolution / max(float(np.hypot(pts[:, 0], pts[:, 1]).max()), resolution)


def refine(field: np.ndarray, u: float, v: float, yaw: float, pts: np.ndarray, resolution: float):
    """Sub-cell pose maximizing the interpolated field (Nelder-Mead within a cell):
    (u, v, yaw, score)."""
    px, py = pts[:, 0] / resolution, pts[:, 1] / resolution
    yaw_unit = one_cell_angle(pts, resolution)

    def cost(z):
        pose = np.array([[u + z[0], v + z[1], yaw + z[2] * yaw_unit]])
        return -field_means(field, pose, px, py)[0]

    r = minimize(cost, np.zeros(3), method='Nelder-Mead',
                 options={'xatol': 0.02, 'fatol': 1e-5, 'initial_simplex': np.array(
                     [[0, 0, 0], [0.5, 0, 0], [0, 0.5, 0], [0, 0, 0.5]]), 'maxiter': 200})
    z = r.x if -r.fun >= -cost(np.zeros(3)) else np.zeros(3)
    return u + z[0], v + z[1], yaw + z[2] * yaw_unit, -cost(z)


class PixelPose(NamedTuple):
    """A pose in the map's pixels as the refinement gives it: column u, row v, heading."""
    u: float
    v: float
    yaw: float


def landscape_covariance(field: np.ndarray, frame: GridFrame, peak: PixelPose, pts: np.ndarray,
                         sigma_cells: float, half: int = 3) -> np.ndarray:
    """(x, y, yaw) covariance in the world frame: the score landscape around a peak plus
    the disagreement of the scan and the map at it (residual_spread).

    The landscape: scores on a (2 half + 1)^3 grid of cell and one-cell-at-max-range steps,
    weighted as likelihoods (s / s_max)^N of N independent points - the shape of the
    answer's uncertainty along a corridor or round a pillar. Near a good fit it is
    narrower than a cell: what remains is not the points' independent noise but what they
    share, the map drawn at its resolution and registered from another run, so the
    residuals at the peak say how far the pose may be off (residual_spread)."""
    u, v, yaw = peak
    res = frame.resolution
    d_yaw = one_cell_angle(pts, res)
    steps = np.arange(-half, half + 1, dtype=float)
    du, dv, da = (g.ravel() for g in np.meshgrid(steps, steps, steps * d_yaw, indexing='ij'))
    poses = np.stack([u + du, v + dv, yaw + da], axis=1)
    scores = np.maximum(field_means(field, poses, pts[:, 0] / res, pts[:, 1] / res), 1e-9)
    w = np.exp(len(pts) * (np.log(scores) - np.log(scores.max())))
    w /= w.sum()
    offsets = np.stack([*frame.pixel_steps_to_grid(du, dv), da], axis=1)
    mean = w @ offsets
    cov = (offsets - mean).T @ ((offsets - mean) * w[:, None])
    spread, reach = residual_spread(field, peak, pts, res, sigma_cells)
    # a shift of length d: d^2 / 2 on each axis; a turn moving the points by d at their range
    cov += np.diag([spread * res ** 2 / 2, spread * res ** 2 / 2, spread / reach ** 2])
    return frame.covariance_to_world(cov)


def residual_spread(field: np.ndarray, peak: PixelPose, pts: np.ndarray, resolution: float,
                    sigma_cells: float) -> tuple[float, float]:
    """(mean squared residual, RMS range) in cells of the points the map explains at the
    pose (within 3 sigma of a wall: the field exp(-d^2 / 2 sigma^2) read back as d). A scan
    and a map that disagree by d at every wall - the map's cells (at least a uniform cell's
    1/12), a map built from another run registered a few cm differently, the scan's noise
    - hold the pose only to about d: a shift of d, or a turn moving the points by d at
    their range, fits about as well."""
    px, py = pts[:, 0] / resolution, pts[:, 1] / resolution
    within = math.exp(-0.5 * 3.0 ** 2)      # the field 3 sigma from a wall
    f = field_samples(field, np.array([list(peak)]), px, py)[0]
    explained = f > within
    if explained.sum() < 3:
        explained = np.ones(len(f), bool)
    d2 = -2.0 * sigma_cells ** 2 * np.log(np.clip(f[explained], within, 1.0))
    reach = math.sqrt(float(np.mean(px[explained] ** 2 + py[explained] ** 2)))
    return max(float(d2.mean()), 1.0 / 12.0), max(reach, 1.0)


def warm_up() -> None:
    # the layout the matcher passes: a strided view of the first plane (see grids)
    field_means(np.zeros((4, 4), np.uint8)[1:3, 1:3], np.zeros((1, 3)), np.zeros(1), np.zeros(1))
    field_samples(np.zeros((4, 4), np.uint8)[1:3, 1:3], np.zeros((1, 3)), np.zeros(1), np.zeros(1))
