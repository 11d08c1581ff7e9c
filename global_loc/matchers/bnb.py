"""Exact global search by multi-resolution branch and bound over (x, y, yaw), after
Cartographer's FastCorrelativeScanMatcher2D (Hess et al. 2016), then sub-cell refinement.

Scoring: the scan's points against a likelihood field of the map (exp(-d^2 / 2 sigma^2)
of the distance d to the nearest occupied cell), not a rasterized image of the scan.
The score of a pose is the field's mean over the scan's points, in [0, 1]: about the
fraction of the scan the map explains.

Search: leaf poses are the laser on a cell centre at angles k * d0, d0 = acos(1 -
res^2 / (2 r_max^2)) (a point at the scan's largest range moves at most one cell
between neighbouring angles). A node at level h covers 2^h x 2^h cells and 2^h angles;
its bound reads the scan, rotated to the node's middle angle, from grids whose cells
hold the field's maximum over the block, widened by the rotation's reach: a point at
range r moves at most (2^h - 1) / 2 * r / r_max cells over the node's angles, plus one
cell of rounding, so each point reads the grid widened just enough for its own range
(near points, most of an indoor scan, get tight bounds). A bound is never below any leaf under
it, and pruning by bound loses no pose scoring above the pruning threshold: the search
is exact at cell and d0 resolution. The laser must stand on a free cell of the map.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import map_coordinates
from scipy.optimize import minimize

from ..map_io import OccupancyMap
from ..transform import Rigid2D
from .base import Candidate, Matcher, Verdict, distinct


@dataclass
class BranchAndBoundOptions:
    sigma_cells: float = 1.5       # likelihood field width, cells
    levels: int = 7                # blocks of 1 .. 64 cells
    max_points: int = 240          # scan points kept after the one-cell voxel filter
    max_range: float = 30.0        # m; farther returns are left out (the angle step shrinks
                                   # with the largest range, and far returns are the least sure)
    keep_ratio: float = 0.9        # nodes bounded above keep_ratio x best score are explored:
                                   # every pose scoring that high is found (the hypotheses)
    max_nodes: int = 60000         # expansions; past it the search stops (and says it was not exhaustive)
    hypotheses: int = 8            # distinct poses refined and returned
    distinct_cells: float = 16.0   # poses closer than this (and < distinct_angle) are one peak
    distinct_angle: float = math.radians(20.0)
    # Confidence = (margin of the best over the next distinct peak, relative to the best,
    # over 1 - keep_ratio, the largest margin the search can see) x (how much of the
    # scan the map explains: (score - 0.3) / 0.3, clipped). success: confidence at least
    # min_confidence.
    min_confidence: float = 0.5


MARGINS = (0, 1, 2, 3, 5, 9, 17, 33)   # widenings (cells) for which grids are kept


class PrecomputationGridStack:
    """Per map, built once: the likelihood field, max-pooled uint8 grids per level and
    widening, and per level whether a block holds a free cell. Memory: `nbytes`."""

    def __init__(self, occupancy_map: OccupancyMap, options: BranchAndBoundOptions):
        self.options = options
        occupied = occupancy_map.occupied
        dist = cv2.distanceTransform((~occupied).astype(np.uint8), cv2.DIST_L2, 5) if occupied.any() \
            else np.full(occupied.shape, 1e6, np.float32)
        self.field = np.exp(-(dist.astype(np.float32) ** 2) / (2.0 * options.sigma_cells ** 2))
        top = options.levels - 1
        self.pad = (2 ** top) + 2 * self.margin(top) + 2
        p = self.pad
        base = cv2.copyMakeBorder(np.rint(self.field * 255).astype(np.uint8), p, p, p, p, cv2.BORDER_CONSTANT, value=0)
        free = occupancy_map.free.astype(np.uint8)
        free = cv2.copyMakeBorder(free, p, p, p, p, cv2.BORDER_CONSTANT, value=0)
        self.grids, self.free_blocks = {}, []
        for h in range(options.levels):
            size = 2 ** h
            for m in MARGINS:
                width = size + 2 * m
                self.grids[h, m] = base if width == 1 else \
                    cv2.dilate(base, np.ones((width, width), np.uint8), anchor=(m, m))
                if m >= self.margin(h):
                    break
            # dilate's window at (x, y) spans [x - anchor, x - anchor + size): the block itself
            self.free_blocks.append(free if size == 1 else
                                    cv2.dilate(free, np.ones((size, size), np.uint8), anchor=(0, 0)))
        self.nbytes = self.field.nbytes + sum(g.nbytes for g in self.grids.values() if g is not base) + \
            base.nbytes + sum(f.nbytes for f in self.free_blocks)

    @staticmethod
    def margin(level: int, range_fraction: float = 1.0) -> int:
        """Cells a point at range_fraction x r_max may move within a level-`level` node's
        angles, plus one of rounding."""
        return 0 if level == 0 else int(math.ceil((2 ** level - 1) / 2.0 * range_fraction + 1e-3)) + 1

    def margin_groups(self, level: int, ranges: np.ndarray, r_max: float) -> list[tuple[int, np.ndarray]]:
        """(widening, indices of the points that need it) for one level."""
        # margin() for every point at once (this runs in every bound evaluation)
        need = np.zeros(len(ranges), int) if level == 0 else \
            np.ceil((2 ** level - 1) / 2.0 * (ranges / r_max) + 1e-3).astype(int) + 1
        available = np.array([m for m in MARGINS if (level, m) in self.grids])
        use = available[np.searchsorted(available, need)]
        return [(int(m), np.flatnonzero(use == m)) for m in np.unique(use)]


class BranchAndBoundMatcher(Matcher):
    name = 'bnb'
    min_score = 0.0

    def __init__(self, occupancy_map: OccupancyMap, options: BranchAndBoundOptions | None = None):
        super().__init__(occupancy_map)
        self.options = options or BranchAndBoundOptions()
        self.last_search: dict = {}
        self.stack = PrecomputationGridStack(occupancy_map, self.options)

    def judge(self, scores):
        """See BranchAndBoundOptions: a near-tie with another place is "ambiguous", a
        scan the map explains poorly is a "poor match"; neither is a success."""
        opt = self.options
        if not scores:
            return Verdict(False, 0.0, 'bnb found no pose on free space')
        if not self.last_search.get('exact', True):
            # The node budget ran out: a better place may be unexplored, so no margin holds.
            return Verdict(False, 0.0, f'search incomplete: stopped after {opt.max_nodes} node expansions; '
                                       f'best of what was explored, see the hypotheses')
        best = scores[0]
        # No other peak found means none scored above keep_ratio x best.
        second = scores[1] if len(scores) > 1 else opt.keep_ratio * best
        margin = (best - second) / best if best > 0 else 0.0
        explained = float(np.clip((best - 0.3) / 0.3, 0.0, 1.0))
        conf = float(np.clip(margin / (1.0 - opt.keep_ratio), 0.0, 1.0)) * explained
        if conf >= opt.min_confidence:
            return Verdict(True, conf, 'localized')
        if explained < 1.0 and explained * 1.0 < opt.min_confidence:
            return Verdict(False, conf, f'poor match: the map explains about {100 * best:.0f}% of the scan')
        close = sum(s >= best * (1.0 - 2 * margin) for s in scores[1:]) if margin > 0 else len(scores) - 1
        return Verdict(False, conf, f'ambiguous: {max(close, 1)} other place(s) match within '
                                    f'{100 * margin:.1f}% of the best; see the hypotheses')

    # ---- scan preparation --------------------------------------------------------
    def prepare(self, points: np.ndarray) -> np.ndarray:
        """One point per cell (voxel filter), at most max_points of them, evenly chosen."""
        res = self.map.resolution
        points = points[np.hypot(points[:, 0], points[:, 1]) <= self.options.max_range]
        keys = np.floor(points / res).astype(np.int64)
        _, first = np.unique(keys, axis=0, return_index=True)
        pts = points[np.sort(first)]
        if len(pts) > self.options.max_points:
            pts = pts[np.linspace(0, len(pts) - 1, self.options.max_points).astype(int)]
        return pts

    def offsets(self, pts: np.ndarray, angle: float) -> tuple[np.ndarray, np.ndarray]:
        """Pixel offsets (du, dv) of the points rotated by `angle` in the map's grid frame."""
        c, s = math.cos(angle), math.sin(angle)
        x = (c * pts[:, 0] - s * pts[:, 1]) / self.map.resolution
        y = (s * pts[:, 0] + c * pts[:, 1]) / self.map.resolution
        return np.rint(x).astype(np.int64), np.rint(-y).astype(np.int64)

    # ---- scoring -------------------------------------------------------------------
    def bounds(self, level: int, tu, tv, ta, pts, d0) -> np.ndarray:
        """Bounds (level > 0) or exact scores (level 0) of nodes (tu, tv, ta), in [0, 1].
        All nodes at once: per-angle point offsets, one gather per widening group."""
        p = self.stack.pad
        ranges = np.hypot(pts[:, 0], pts[:, 1])
        groups = self.stack.margin_groups(level, ranges, max(float(ranges.max()), 1e-9))
        angles, which = np.unique(ta, return_inverse=True)
        theta = (angles + (2 ** level - 1) / 2.0) * d0
        c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
        res = self.map.resolution
        du = np.rint((c * pts[:, 0] - s * pts[:, 1]) / res).astype(np.int32)     # (angles, points)
        dv = np.rint(-(s * pts[:, 0] + c * pts[:, 1]) / res).astype(np.int32)
        height, width = self.stack.grids[0, 0].shape
        out = np.zeros(len(tu), np.float64)
        step = max(1, 4_000_000 // max(len(pts), 1))
        for lo in range(0, len(tu), step):
            sl = slice(lo, lo + step)
            u = du[which[sl]] + (tu[sl, None] + p).astype(np.int32)
            v = dv[which[sl]] + (tv[sl, None] + p).astype(np.int32)
            # Outside the padded grid every grid is zero: clamping onto its zero border is exact.
            np.clip(u, 0, width - 1, out=u)
            np.clip(v, 0, height - 1, out=v)
            flat = v * width + u
            for m, idx in groups:
                out[sl] += np.take(self.stack.grids[level, m].ravel(), flat[:, idx]).sum(axis=1, dtype=np.int64)
        return out / (255.0 * len(pts))

    def free(self, level: int, tu, tv) -> np.ndarray:
        p = self.stack.pad
        return self.stack.free_blocks[level][tv + p, tu + p] > 0

    @staticmethod
    def children(tu, tv, ta, level):
        """The 8 children (4 blocks x 2 angle halves) of each level-`level` node."""
        half = 2 ** (level - 1)
        du = np.array([0, half, 0, half, 0, half, 0, half])
        dv = np.array([0, 0, half, half, 0, 0, half, half])
        da = np.array([0, 0, 0, 0, half, half, half, half])
        return ((tu[:, None] + du).ravel(), (tv[:, None] + dv).ravel(), (ta[:, None] + da).ravel())

    # ---- search --------------------------------------------------------------------
    def match(self, points, options, progress=None):
        opt = self.options
        pts = self.prepare(points.points)
        if len(pts) < 3:
            return []
        res = self.map.resolution
        r_max = max(float(np.hypot(pts[:, 0], pts[:, 1]).max()), 3 * res)
        top = opt.levels - 1
        n_angles = int(math.ceil(2 * math.pi / math.acos(1 - res ** 2 / (2 * r_max ** 2)) / 2 ** top)) * 2 ** top
        d0 = 2 * math.pi / n_angles
        step = 2 ** top
        gu, gv, ga = np.meshgrid(np.arange(0, self.map.width, step), np.arange(0, self.map.height, step),
                                 np.arange(0, n_angles, step), indexing='ij')
        tu, tv, ta = gu.ravel(), gv.ravel(), ga.ravel()
        keep = self.free(top, tu, tv)
        tu, tv, ta = tu[keep], tv[keep], ta[keep]
        if len(tu) == 0:
            return []
        b = self.bounds(top, tu, tv, ta, pts, d0)
        leaves, exact = self.best_first(tu, tv, ta, b, top, pts, d0, n_angles, progress)
        lu, lv, la, ls = leaves
        self.last_search = {'exact': exact, 'angles': n_angles, 'points': len(pts), 'leaves': len(ls),
                            'best_leaf': float(ls.max()) if len(ls) else 0.0}
        return self.refine_peaks(lu, lv, la, ls, pts, d0, progress)

    def best_first(self, tu, tv, ta, b, top, pts, d0, n_angles, progress, batch: int = 512):
        """Branch and bound, depth first, `batch` nodes expanded at a time. Every
        node whose bound reaches keep_ratio x the best leaf so far is expanded; returns
        the leaves scoring that high (u, v, angle index, score) and whether the search
        was exhaustive (False when max_nodes stopped it)."""
        opt = self.options
        level = np.full(len(tu), top, np.int8)
        lower, expanded = 0.0, 0
        found = [np.zeros(0, np.int64)] * 3 + [np.zeros(0)]
        while len(b):
            threshold = opt.keep_ratio * lower
            live = b >= threshold
            tu, tv, ta, b, level = tu[live], tv[live], ta[live], b[live], level[live]
            if not len(b):
                break
            if expanded >= opt.max_nodes:
                return self._keep(found, threshold), False
            # Deepest live nodes first, best bound first among them (Cartographer's depth-first
            # order, in batches): leaves come early, and with them a pruning threshold.
            deepest = np.flatnonzero(level == level.min())
            pick = deepest[np.argpartition(-b[deepest], batch - 1)[:batch]] if len(deepest) > batch else deepest
            rest = np.ones(len(b), bool)
            rest[pick] = False
            new = []
            for h in np.unique(level[pick]):
                sel = pick[level[pick] == h]
                u, v, a = self.children(tu[sel], tv[sel], ta[sel], int(h))
                ok = (u < self.map.width) & (v < self.map.height) & (a < n_angles)
                u, v, a = u[ok], v[ok], a[ok]
                ok = self.free(int(h) - 1, u, v)
                u, v, a = u[ok], v[ok], a[ok]
                cb = self.bounds(int(h) - 1, u, v, a, pts, d0)
                expanded += len(sel)
                if h == 1:   # children are leaves: exact scores
                    if len(cb):
                        lower = max(lower, float(cb.max()))
                    found = [np.concatenate([f, x]) for f, x in zip(found, (u, v, a, cb))]
                    found = self._keep(found, opt.keep_ratio * lower)
                else:
                    new.append((u, v, a, cb, np.full(len(u), h - 1, np.int8)))
            tu, tv, ta, b, level = tu[rest], tv[rest], ta[rest], b[rest], level[rest]
            for u, v, a, cb, lv in new:
                tu, tv, ta = np.concatenate([tu, u]), np.concatenate([tv, v]), np.concatenate([ta, a])
                b, level = np.concatenate([b, cb]), np.concatenate([level, lv])
            if progress:
                progress(min(0.95, expanded / opt.max_nodes), lower)
        return self._keep(found, opt.keep_ratio * lower), True

    @staticmethod
    def _keep(found, threshold):
        keep = found[3] >= threshold
        return [f[keep] for f in found]

    # ---- peaks and refinement ----------------------------------------------------
    def refine_peaks(self, tu, tv, ta, scores, pts, d0, progress):
        opt = self.options
        leaves = [Candidate(self.laser_pose(float(u), float(v), float(a * d0)), float(sc))
                  for u, v, a, sc in zip(tu, tv, ta, scores)]
        peaks = distinct(leaves, opt.hypotheses, opt.distinct_cells * self.map.resolution, opt.distinct_angle)
        grid_T_map = self.map.origin.inverse()
        starts = []
        for c in peaks:   # back to (u, v, grid-frame yaw) for the refinement
            g = grid_T_map * c.laser_pose
            u, v = self.map.grid_to_pixel([[g.x, g.y]])[0]
            starts.append((float(u), float(v), g.yaw))
        refined = sorted((self.refine(u, v, yaw, pts) for u, v, yaw in starts), key=lambda r: -r[3])
        out = [Candidate(self.laser_pose(u, v, yaw), score) for u, v, yaw, score in refined]
        if out:
            out[0].covariance = self.landscape_covariance(*refined[0][:3], pts)
        if progress:
            progress(1.0, out[0].score if out else 0.0)
        return out

    def landscape_covariance(self, u, v, yaw, pts, half: int = 3) -> np.ndarray:
        """(x, y, yaw) covariance in the map frame from the score landscape around a
        peak: scores on a (2 half + 1)^3 grid of cell and one-cell-at-max-range steps,
        weighted as likelihoods (s / s_max)^N of N independent points, plus the
        search's own resolution (a uniform cell and angle step: step^2 / 12)."""
        res = self.map.resolution
        d_yaw = res / max(float(np.hypot(pts[:, 0], pts[:, 1]).max()), res)
        steps = np.arange(-half, half + 1, dtype=float)
        du, dv, da = (g.ravel() for g in np.meshgrid(steps, steps, steps * d_yaw, indexing='ij'))
        c, s = np.cos(yaw + da)[:, None], np.sin(yaw + da)[:, None]
        x = u + du[:, None] + (c * pts[:, 0] - s * pts[:, 1]) / res
        y = v + dv[:, None] - (s * pts[:, 0] + c * pts[:, 1]) / res
        scores = map_coordinates(self.stack.field, [y.ravel(), x.ravel()], order=1, mode='constant',
                                 cval=0.0).reshape(len(du), -1).mean(axis=1)
        scores = np.maximum(scores, 1e-9)
        w = np.exp(len(pts) * (np.log(scores) - np.log(scores.max())))
        w /= w.sum()
        offsets = np.stack([du * res, -dv * res, da], axis=1)      # grid frame: v points down
        mean = w @ offsets
        cov = (offsets - mean).T @ ((offsets - mean) * w[:, None])
        cov += np.diag([res ** 2 / 12, res ** 2 / 12, d_yaw ** 2 / 12])
        rot = np.eye(3)
        cy, sy = math.cos(self.map.origin.yaw), math.sin(self.map.origin.yaw)
        rot[:2, :2] = [[cy, -sy], [sy, cy]]
        return rot @ cov @ rot.T

    def mean_field(self, u, v, yaw, pts) -> float:
        c, s = math.cos(yaw), math.sin(yaw)
        res = self.map.resolution
        x = u + (c * pts[:, 0] - s * pts[:, 1]) / res
        y = v - (s * pts[:, 0] + c * pts[:, 1]) / res
        return float(map_coordinates(self.stack.field, [y, x], order=1, mode='constant', cval=0.0).mean())

    def refine(self, u, v, yaw, pts):
        """Sub-cell pose maximizing the interpolated field (Nelder-Mead within a cell)."""
        res = self.map.resolution
        scale = np.array([1.0, 1.0, res / max(float(np.hypot(pts[:, 0], pts[:, 1]).max()), res)])

        def cost(z):
            return -self.mean_field(u + z[0], v + z[1], yaw + z[2] * scale[2], pts)

        r = minimize(cost, np.zeros(3), method='Nelder-Mead',
                     options={'xatol': 0.02, 'fatol': 1e-5, 'initial_simplex': np.array(
                         [[0, 0, 0], [0.5, 0, 0], [0, 0.5, 0], [0, 0, 0.5]]), 'maxiter': 200})
        z = r.x if -r.fun >= -cost(np.zeros(3)) else np.zeros(3)
        return u + z[0], v + z[1], yaw + z[2] * scale[2], -cost(z)

    def laser_pose(self, u: float, v: float, yaw: float) -> Rigid2D:
        """Laser at continuous pixel (u, v) with grid-frame heading yaw -> map frame."""
        gx, gy = self.map.pixel_to_grid([[u, v]])[0]
        return self.map.origin * Rigid2D(float(gx), float(gy), yaw)
