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
(near points, most of an indoor scan, get tight bounds). A bound is never below any leaf
under it, and pruning by bound loses no pose scoring above the pruning threshold: the
search is exact at cell and d0 resolution. Nodes are expanded best bound first
(bnb_kernel, compiled), down to keep_ratio x the best leaf, so every pose scoring that
high is found: the hypotheses, and the margin behind the confidence. The laser must
stand on a free cell of the map.

Free space: the field only rewards end points, so a pose whose beams pass through mapped
walls to reach them (a corridor matched 180 deg reversed, a twin room behind a closed
door) can score as high as the truth. Each refined hypothesis is therefore also checked
ray by ray (bnb_kernel.see_through): the fraction of beams, returns and no-returns, that
cross an occupied cell before their end. The ranking score is the field score x (1 -
that fraction). It can reorder the hypotheses, but a confident answer also needs a margin
on the field score alone: the ray test decides between poses, it never vouches for one
(transient things in the map - people, doors - make true poses fail it for some beams on
real maps).
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import minimize

from ..map_io import OccupancyMap
from ..transform import Rigid2D
from .base import Candidate, Matcher, Verdict, distinct
from .bnb_kernel import (PAD, field_means, make_heap, node_bounds, offset_tables, search_step, see_through, split_heap,
                         warm_up)


@dataclass
class BranchAndBoundOptions:
    sigma_cells: float = 1.5       # likelihood field width, cells
    levels: int = 7                # blocks of 1 .. 64 cells
    max_points: int = 240          # scan points kept after the one-cell voxel filter
    max_range: float = 30.0        # m; farther returns are left out (the angle step shrinks
                                   # with the largest range, and far returns are the least sure)
    keep_ratio: float = 0.9        # nodes bounded above keep_ratio x best score are explored:
                                   # every pose scoring that high is found (the hypotheses)
    max_nodes: int = 400000        # expansions; past it the search stops (and says it was not exhaustive)
    hypotheses: int = 8            # distinct poses refined and returned
    distinct_cells: float = 16.0   # poses closer than this (and < distinct_angle) are one peak
    distinct_angle: float = math.radians(20.0)
    see_through_tolerance_cells: float = 3.0   # a return's beam is checked up to this short of
                                   # its end (noise, the wall's cells, grazing beams)
    # Confidence = (margin of the best over the next distinct peak, relative to the best,
    # over 1 - keep_ratio, the largest margin the search can see) x (how much of the
    # scan the map explains: (score - 0.3) / 0.3, clipped). success: confidence at least
    # min_confidence.
    min_confidence: float = 0.5


MARGINS = (0, 1, 2, 3, 5, 9, 17, 33)   # widenings (cells) for which grids are kept
PLANE_SHIFT_FROM = 3                   # planes of level h > this are stored at 1 / 2^(h - this)
                                       # resolution (see PrecomputationGridStack)


class PrecomputationGridStack:
    """Per map, built once: the likelihood field; per level and widening a uint8 plane
    whose cell holds the field's maximum over the block starting there and the widening
    around it (`grid_ids` picks one per point); per level, whether each block holds a
    free cell. Memory: `nbytes`.

    The search is bound by memory latency (a node reads ~200 scattered cells), so the
    planes are kept small: a level-h plane (windows of 2^h cells and more) is stored at
    1 / 2^shift[h] of the map's resolution, each stored cell the maximum over the
    2^shift x 2^shift cells it stands for. That widens each window by under 2^shift
    cells - a looser but still valid bound - and divides the memory the upper levels
    read by 4^shift. All planes are one flat array (`flat`, plane k from offsets[k]),
    read by the kernel as flat[offsets[k] + (y >> shift[h]) * plane_width[h] + (x >> shift[h])]."""

    def __init__(self, occupancy_map: OccupancyMap, options: BranchAndBoundOptions):
        self.options = options
        top = options.levels - 1
        # The widest plane must cover the top level's heading spread (else its bounds would
        # not be bounds), and the kernel's heap keys hold the level in 3 bits.
        most = max(n for n in range(1, 9) if self.margin(n - 1) <= MARGINS[-1])
        if not 1 <= options.levels <= most:
            raise ValueError(f'bnb levels must be 1 .. {most}, got {options.levels}')
        occupied = occupancy_map.occupied
        self.occupied = occupied.astype(np.uint8)     # for the free-space check
        dist = cv2.distanceTransform((~occupied).astype(np.uint8), cv2.DIST_L2, 5) if occupied.any() \
            else np.full(occupied.shape, 1e6, np.float32)
        self.field = np.exp(-(dist.astype(np.float32) ** 2) / (2.0 * options.sigma_cells ** 2))
        self.pad = (2 ** top) + 2 * int(self.margin(top)) + 2
        p = self.pad
        self.shift = np.array([max(0, h - PLANE_SHIFT_FROM) for h in range(options.levels)], np.int64)
        unit = 2 ** int(self.shift.max())
        # padded so that every plane's size divides evenly
        height, width = (-(-(n + 2 * p) // unit) * unit for n in occupied.shape)
        self.height, self.width = height, width
        base = np.zeros((height, width), np.uint8)
        base[p:p + occupied.shape[0], p:p + occupied.shape[1]] = np.rint(self.field * 255).astype(np.uint8)
        self.index: dict[tuple[int, int], int] = {}
        for h in range(options.levels):
            for m in MARGINS:
                self.index[h, m] = len(self.index)
                if m >= self.margin(h):
                    break
        planes, plane = [], np.empty_like(base)
        for (h, m), i in self.index.items():
            k = 2 ** int(self.shift[h])
            # dilate's window at (x, y) spans [x - anchor, x - anchor + size): the block and m
            # around it, and the k - 1 cells after it that the stored cell (x, y) also stands for
            size = 2 ** h + 2 * m + k - 1
            cv2.dilate(base, np.ones((size, size), np.uint8), dst=plane, anchor=(m, m))
            planes.append(plane[::k, ::k].flatten())     # a copy: plane is reused
        self.plane_width = np.array([width >> int(s) for s in self.shift], np.int64)
        self.offsets = np.cumsum([0] + [len(q) for q in planes[:-1]]).astype(np.int64)
        self.flat = np.concatenate(planes)
        # free_blocks: per level h, block (u >> h, v >> h) of the map holds a free cell
        free = occupancy_map.free
        self.free_offsets, self.free_width, blocks = [], [], []
        for h in range(options.levels):
            k = 2 ** h
            rows, cols = -(-free.shape[0] // k), -(-free.shape[1] // k)
            padded = np.zeros((rows * k, cols * k), bool)
            padded[:free.shape[0], :free.shape[1]] = free
            self.free_offsets.append(sum(len(b) for b in blocks))
            self.free_width.append(cols)
            blocks.append(padded.reshape(rows, k, cols, k).any(axis=(1, 3)).astype(np.uint8).ravel())
        self.free_blocks = np.concatenate(blocks)
        self.free_offsets = np.array(self.free_offsets, np.int64)
        self.free_width = np.array(self.free_width, np.int64)
        self.nbytes = self.field.nbytes + self.flat.nbytes + self.free_blocks.nbytes + self.occupied.nbytes

    def layout(self):
        """What the kernel needs to find a cell: (shift, plane_width, pad, width, height)."""
        return self.shift, self.plane_width, self.pad, self.width, self.height

    def free_block(self, level: int, u, v):
        """Whether the level's blocks starting at map cells (u, v) hold a free cell."""
        return self.free_blocks[self.free_offsets[level] + (np.asarray(v) >> level) * self.free_width[level]
                                + (np.asarray(u) >> level)] > 0

    @staticmethod
    def margin(level: int, range_fraction=1.0):
        """Cells a point at range_fraction x r_max may move within a level-`level` node's
        2^level angles (about the middle one), plus one of rounding. range_fraction may
        be an array (one per point)."""
        if level == 0:
            return np.zeros_like(range_fraction, dtype=int)
        return np.ceil((2 ** level - 1) / 2.0 * np.asarray(range_fraction) + 1e-3).astype(int) + 1

    def grid_ids(self, ranges: np.ndarray, r_max: float) -> np.ndarray:
        """(levels, points): the grid each point reads at each level, the one widened
        just enough for the point's range."""
        out = np.array([[self.index[h, 0]] * len(ranges) for h in range(self.options.levels)], np.int64)
        for h in range(1, self.options.levels):
            need = self.margin(h, ranges / r_max)
            available = np.array([m for m in MARGINS if (h, m) in self.index])
            use = available[np.searchsorted(available, need)]
            out[h] = [self.index[h, int(m)] for m in use]
        return out


class BranchAndBoundMatcher(Matcher):
    name = 'bnb'
    min_score = 0.0

    def __init__(self, occupancy_map: OccupancyMap, options: BranchAndBoundOptions | None = None):
        super().__init__(occupancy_map)
        self.options = options or BranchAndBoundOptions()
        self.last_search: dict = {}
        self._executor, self._executor_threads = None, 0    # the search's threads (_pool)
        self.stack = PrecomputationGridStack(occupancy_map, self.options)
        warm_up()

    def judge(self, candidates):
        """See BranchAndBoundOptions: a near-tie with another place is "ambiguous", a
        scan the map explains poorly is a "poor match"; neither is a success. The margin
        is the smaller of the ranking score's (free space counted) and the field score's
        (see the module doc)."""
        opt = self.options
        if not candidates:
            return Verdict(False, 0.0, 'bnb found no pose on free space')
        if not self.last_search.get('exact', True):
            # The node budget ran out: a better place may be unexplored, so no margin holds.
            return Verdict(False, 0.0, f'search incomplete: stopped after {opt.max_nodes} node expansions; '
                                       f'best of what was explored, see the hypotheses')
        best, others = candidates[0], candidates[1:]
        fit = [c.explained for c in candidates]     # refine_peaks sets it on every candidate
        # No other peak found means none scored above keep_ratio x best (in either score).
        second = others[0].score if others else opt.keep_ratio * best.score
        rival = max(fit[1:] + [opt.keep_ratio * max(fit)])
        rank_margin = (best.score - second) / best.score if best.score > 0 else 0.0
        fit_margin = (fit[0] - rival) / fit[0] if fit[0] > 0 else 0.0
        margin = min(rank_margin, fit_margin)
        explained = float(np.clip((fit[0] - 0.3) / 0.3, 0.0, 1.0))
        conf = float(np.clip(margin / (1.0 - opt.keep_ratio), 0.0, 1.0)) * explained
        if conf >= opt.min_confidence:
            return Verdict(True, conf, 'localized')
        if explained < 1.0 and explained < opt.min_confidence:
            return Verdict(False, conf, f'poor match: the map explains about {100 * fit[0]:.0f}% of the scan')
        if fit_margin < 0 and others:
            rival_c = max(others, key=lambda c: c.explained)
            return Verdict(False, conf, f'ambiguous: another place explains the scan as well or better, but '
                                        f'{100 * (rival_c.see_through or 0.0):.0f}% of its beams would pass through '
                                        f'walls ({100 * (best.see_through or 0.0):.0f}% for the best); '
                                        f'see the hypotheses')
        # the rivals: every other place within the lead a confident answer needs at this fit
        # (not only those within twice the margin: exact twins differ by rounding, ~1e-15)
        need = opt.min_confidence * (1.0 - opt.keep_ratio) / explained
        close = sum(c.score >= best.score * (1.0 - need) for c in others)
        return Verdict(False, conf, f'ambiguous: {max(close, 1)} other place(s) within {100 * need:.0f}% of the '
                                    f'best (the closest {100 * max(margin, 0.0):.1f}% behind); see the hypotheses')

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

    # ---- scoring -------------------------------------------------------------------
    def tables(self, pts: np.ndarray, d0: float, n_angles: int):
        """What the kernel reads for this scan: per level h, the points' cell offsets at
        the middle angle of each node's angles (rows row_start[h] + a >> h), and where in
        the flat grids the grid each point reads (grid_ids) starts."""
        res = self.map.resolution
        ranges = np.hypot(pts[:, 0], pts[:, 1])
        gid = self.stack.grid_ids(ranges, max(float(ranges.max()), 1e-9))
        thetas, row_start = [], []
        for h in range(self.options.levels):
            row_start.append(sum(len(t) for t in thetas))
            size = 2 ** h
            thetas.append((np.arange(0, n_angles, size) + (size - 1) / 2.0) * d0)
        du, dv = offset_tables(np.concatenate(thetas), pts[:, 0] / res, pts[:, 1] / res)   # (rows, points)
        return (self.stack.offsets[gid], du, dv, np.array(row_start, np.int64)) + self.stack.layout()

    def bounds(self, level: int, tu, tv, ta, pts, d0) -> np.ndarray:
        """Bounds (level > 0) or exact scores (level 0) of nodes (tu, tv, ta), in [0, 1]."""
        n_angles = int(round(2 * math.pi / d0))
        raw = node_bounds(self.stack.flat, *self.tables(pts, d0, n_angles), np.asarray(tu, np.int64),
                          np.asarray(tv, np.int64), np.asarray(ta, np.int64), level)
        return raw / (255.0 * len(pts))

    # ---- search --------------------------------------------------------------------
    @staticmethod
    def threads() -> int:
        """Search threads: as many as OpenCV may use (cv2.getNumThreads(), by default one
        per core), so one setting - cv2.setNumThreads - governs every matcher; the
        benchmark gives each worker process its share of the cores that way."""
        return max(1, cv2.getNumThreads())

    def _pool(self, threads: int) -> ThreadPoolExecutor:
        if self._executor is None or self._executor_threads != threads:
            self._executor, self._executor_threads = ThreadPoolExecutor(threads, thread_name_prefix='bnb'), threads
        return self._executor

    def match(self, points, options, progress=None):
        opt = self.options
        pts = self.prepare(points.points)
        if len(pts) < 3:
            return []
        res = self.map.resolution
        r_max = max(float(np.hypot(pts[:, 0], pts[:, 1]).max()), 3 * res)
        top = opt.levels - 1
        step = 2 ** top
        n_angles = int(math.ceil(2 * math.pi / math.acos(1 - res ** 2 / (2 * r_max ** 2)) / step)) * step
        d0 = 2 * math.pi / n_angles
        gu, gv, ga = np.meshgrid(np.arange(0, self.map.width, step), np.arange(0, self.map.height, step),
                                 np.arange(0, n_angles, step), indexing='ij')
        tu, tv, ta = gu.ravel(), gv.ravel(), ga.ravel()
        keep = self.stack.free_block(top, tu, tv)
        tu, tv, ta = tu[keep], tv[keep], ta[keep]
        if len(tu) == 0:
            return []
        tables = self.tables(pts, d0, n_angles)
        b = node_bounds(self.stack.flat, *tables, tu, tv, ta, top)
        leaves, per_level, exact = self.search(np.stack([tu, tv, ta, b], axis=1).astype(np.int64), tables,
                                              n_angles, progress)
        scale = 255.0 * len(pts)
        lu, lv, la, ls = leaves[:, 0], leaves[:, 1], leaves[:, 2], leaves[:, 3] / scale
        self.last_search = {'exact': exact, 'angles': n_angles, 'points': len(pts), 'leaves': len(ls),
                            'expansions': int(per_level.sum()), 'top_nodes': len(tu), 'per_level': per_level.tolist(),
                            'threads': self.threads(),
                            'best_leaf': float(ls.max()) if len(ls) else 0.0}
        return self.refine_peaks(lu, lv, la, ls, pts, d0, points, progress)

    def search(self, top_nodes, tables, n_angles, progress, slice_expansions: int = 20000):
        """Best-first branch and bound (bnb_kernel.search_step), run in slices so that
        progress is reported and a cancel is seen between them. Every node whose bound
        reaches keep_ratio x the best leaf is expanded; returns the leaves scoring that
        high (rows u, v, angle index, raw score), the expansions per level, and whether
        the search was exhaustive (False when max_nodes stopped it).

        On several cores the top nodes are dealt to one heap per thread (the kernel
        releases the GIL); the threads share the best leaf found so far, so each prunes
        by the best any has found. A thread whose heap runs out takes half of the
        fullest one. The result does not depend on the threads: every node reaching
        keep_ratio x the final best is expanded whatever the order."""
        opt = self.options
        threads = self.threads()
        order = np.argsort(-top_nodes[:, 3], kind='stable')     # deal the best nodes evenly
        heaps = [make_heap(top_nodes[order[k::threads]], opt.levels - 1) for k in range(threads)]
        shared_best = np.zeros(PAD, np.int64)
        per_level = [np.zeros(max(opt.levels, PAD), np.int64) for _ in heaps]   # PAD: see bnb_kernel
        expanded, found, done = 0, [], [False] * threads

        def run(k, budget):
            n, done[k], leaves, heaps[k] = search_step(
                self.stack.flat, self.stack.free_blocks, self.stack.free_offsets, self.stack.free_width, *tables,
                self.map.width, self.map.height, n_angles, opt.keep_ratio, heaps[k], shared_best, budget,
                per_level[k])
            return n, leaves

        while True:
            budget = max(1, min(slice_expansions, opt.max_nodes - expanded) // threads)
            if threads == 1:
                results = [run(0, budget)]
            else:
                results = list(self._pool(threads).map(run, range(threads), [budget] * threads))
            expanded += sum(n for n, _ in results)
            found.extend(leaves for _, leaves in results)
            if all(done) or expanded >= opt.max_nodes:
                break
            for k in range(threads):      # an idle thread takes half of the fullest heap
                if done[k]:
                    j = max(range(threads), key=lambda i: heaps[i][2][0])
                    if heaps[j][2][0] > 1:
                        heaps[k], heaps[j] = split_heap(*heaps[j])
                        done[k] = done[j] = False
            if progress:   # the server's progress callback raises Cancelled on a cancel request
                progress(min(0.95, expanded / opt.max_nodes), shared_best[0] / (255.0 * tables[1].shape[1]))
        leaves = np.concatenate(found)
        leaves = leaves[leaves[:, 3] >= opt.keep_ratio * shared_best[0]]
        # in pose order, not the order the threads found them: equal scores then pick the
        # same peaks (bin_maxima) whatever the threads
        leaves = leaves[np.argsort((leaves[:, 0] * self.map.height + leaves[:, 1]) * n_angles + leaves[:, 2])]
        return leaves, np.sum(per_level, axis=0)[:opt.levels], all(done)

    # ---- peaks and refinement ----------------------------------------------------
    def bin_maxima(self, tu, tv, ta, scores, d0, limit: int = 512) -> np.ndarray:
        """Indices of the best leaf in each bin of distinct_cells^2 cells x distinct_angle,
        the `limit` best of them, best first. The non-maximum suppression then sees a few
        hundred poses, not every leaf: a featureless view (a 60 deg glimpse of a straight
        wall) leaves a million poses within keep_ratio of the best."""
        opt = self.options
        cell = max(1, int(opt.distinct_cells))
        a_bin = max(1, int(opt.distinct_angle / d0))
        ku, kv, ka = tu // cell, tv // cell, ta // a_bin
        key = (ku * (self.map.height // cell + 1) + kv) * (int(ta.max(initial=0)) // a_bin + 1) + ka
        order = np.argsort(-scores, kind='stable')
        _, first = np.unique(key[order], return_index=True)
        best = order[first]
        return best[np.argsort(-scores[best], kind='stable')][:limit]

    def refine_peaks(self, tu, tv, ta, scores, pts, d0, points, progress):
        opt = self.options
        leaves = [Candidate(self.laser_pose(float(tu[i]), float(tv[i]), float(ta[i] * d0)), float(scores[i]))
                  for i in self.bin_maxima(tu, tv, ta, scores, d0)]
        peaks = distinct(leaves, opt.hypotheses, opt.distinct_cells * self.map.resolution, opt.distinct_angle)
        grid_T_map = self.map.origin.inverse()
        starts = []
        for c in peaks:   # back to (u, v, grid-frame yaw) for the refinement
            g = grid_T_map * c.laser_pose
            u, v = self.map.grid_to_pixel([[g.x, g.y]])[0]
            starts.append((float(u), float(v), g.yaw))
        refined = np.array([self.refine(u, v, yaw, pts) for u, v, yaw in starts]).reshape(-1, 4)
        through = self.see_through_fractions(refined[:, :3], points)
        rank = refined[:, 3] * (1.0 - through)
        order = np.argsort(-rank, kind='stable')
        out = [Candidate(self.laser_pose(*refined[i, :3]), float(rank[i]), explained=float(refined[i, 3]),
                         see_through=float(through[i])) for i in order]
        if out:
            out[0].covariance = self.landscape_covariance(*refined[order[0], :3], pts)
        if progress:
            progress(1.0, out[0].score if out else 0.0)
        return out

    def see_through_fractions(self, poses: np.ndarray, points) -> np.ndarray:
        """Per pose (rows u, v, grid-frame yaw): the fraction of the scan's beams that would
        pass through an occupied cell - a return's beam up to see_through_tolerance_cells
        short of its end point, a no-return beam over its whole range (up to max_range)."""
        opt = self.options
        res = self.map.resolution
        if len(poses) == 0 or not points.beams:
            return np.zeros(len(poses))
        ranges = np.hypot(points.points[:, 0], points.points[:, 1])
        near = ranges <= opt.max_range
        angles = np.concatenate([np.arctan2(points.points[near, 1], points.points[near, 0]),
                                 points.no_return_angles])
        lengths = np.concatenate([ranges[near] / res - opt.see_through_tolerance_cells,
                                  np.full(len(points.no_return_angles), min(points.range_max, opt.max_range) / res)])
        if len(angles) == 0:
            return np.zeros(len(poses))
        crossed = see_through(self.stack.occupied, np.ascontiguousarray(poses, np.float64),
                              angles.astype(np.float64), lengths.astype(np.float64))
        return crossed / len(angles)

    def landscape_covariance(self, u, v, yaw, pts, half: int = 3) -> np.ndarray:
        """(x, y, yaw) covariance in the map frame from the score landscape around a
        peak: scores on a (2 half + 1)^3 grid of cell and one-cell-at-max-range steps,
        weighted as likelihoods (s / s_max)^N of N independent points, plus the
        search's own resolution (a uniform cell and angle step: step^2 / 12)."""
        res = self.map.resolution
        d_yaw = self.one_cell_angle(pts)
        steps = np.arange(-half, half + 1, dtype=float)
        du, dv, da = (g.ravel() for g in np.meshgrid(steps, steps, steps * d_yaw, indexing='ij'))
        poses = np.stack([u + du, v + dv, yaw + da], axis=1)
        scores = np.maximum(field_means(self.stack.field, poses, pts[:, 0] / res, pts[:, 1] / res), 1e-9)
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

    def one_cell_angle(self, pts) -> float:
        """The turn (rad) that moves the scan's farthest point by one cell (at least a cell
        from the laser): the refinement's heading unit and the covariance's heading step."""
        res = self.map.resolution
        return res / max(float(np.hypot(pts[:, 0], pts[:, 1]).max()), res)

    def refine(self, u, v, yaw, pts):
        """Sub-cell pose maximizing the interpolated field (Nelder-Mead within a cell)."""
        res = self.map.resolution
        px, py = pts[:, 0] / res, pts[:, 1] / res
        yaw_unit = self.one_cell_angle(pts)

        def cost(z):
            pose = np.array([[u + z[0], v + z[1], yaw + z[2] * yaw_unit]])
            return -field_means(self.stack.field, pose, px, py)[0]

        r = minimize(cost, np.zeros(3), method='Nelder-Mead',
                     options={'xatol': 0.02, 'fatol': 1e-5, 'initial_simplex': np.array(
                         [[0, 0, 0], [0.5, 0, 0], [0, 0.5, 0], [0, 0, 0.5]]), 'maxiter': 200})
        z = r.x if -r.fun >= -cost(np.zeros(3)) else np.zeros(3)
        return u + z[0], v + z[1], yaw + z[2] * yaw_unit, -cost(z)

    def laser_pose(self, u: float, v: float, yaw: float) -> Rigid2D:
        """Laser at continuous pixel (u, v) with grid-frame heading yaw -> map frame."""
        gx, gy = self.map.pixel_to_grid([[u, v]])[0]
        return self.map.origin * Rigid2D(float(gx), float(gy), yaw)
