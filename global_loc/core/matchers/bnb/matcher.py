"""BranchAndBoundMatcher: exact global search over (x, y, yaw) after Cartographer's
FastCorrelativeScanMatcher2D (Hess et al. 2016), then refinement, the free-space check
and the verdict - each stage its own module, wired here.

Scoring: the scan's points against a likelihood field of the map (exp(-d^2 / 2 sigma^2)
of the distance d to the nearest occupied cell). The score of a pose is the field's
mean over the scan's points, in [0, 1]: about the fraction of the scan the map explains.

Search: leaf poses are the laser on a cell centre at angles k * d0, d0 = acos(1 -
res^2 / (2 r_max^2)) (a point at the scan's largest range moves at most one cell
between neighbouring angles). A node at level h covers 2^h x 2^h cells and 2^h angles;
its bound reads the scan, rotated to the node's middle angle, from planes whose cells
hold the field's maximum over the block, widened by the rotation's reach for each
point's own range (grids.py). A bound is never below any leaf under it, so the search,
expanding best bound first down to the band below the best leaf that the verdict needs
(verdict.searched_keep; search.py), is exact at cell and d0 resolution and finds every
pose scoring that high: the hypotheses, and the margin behind the confidence. The laser
must stand on a free cell of the map.
"""
from __future__ import annotations

import dataclasses
import math
import time
from typing import Callable, NamedTuple, Optional

import numpy as np

from ...map_io import OccupancyMap
from ...pixel_kernels import warm_up as warm_up_pixel_kernels
from ...scan import ScanPoints, voxel_filter
from ...search_region import SearchRegion
from ...transform import Rigid2D
from ..base import Candidate, Match, Matcher, MatchOptions, ProgressFn
from .early_end import resume_rule, settled_check
from .free_space import see_through_fractions
from .grids import PrecomputationGridStack
from .kernels import ScanTables, SearchSpace, node_bounds, offset_tables, region_mask
from .kernels import warm_up as warm_up_search
from .options import BranchAndBoundOptions
from .peaks import PeakRefiner
from .refine import refine
from .refine import warm_up as warm_up_refine
from .search import (
    Resume,
    RunLimits,
    SearchInput,
    SearchRun,
    SearchStart,
    SearchStats,
    SettledFn,
    ThreadedSearch,
    kept_leaves,
    search_threads,
    top_in_band,
)
from .verdict import confident_fit, explained_share, judge, needed_lead


class TreeSearch(NamedTuple):
    """What the branch and bound of one match found, before its peaks are refined."""
    pts: np.ndarray        # the prepared points searched with
    d0: float              # the leaf angle step
    run: SearchRun
    stats: SearchStats
    stopped: str           # why the search stopped early ('' when it did not)
    space: SearchSpace     # what it searched (the map, the headings, the prior, the band it ended with)
    tops: tuple            # its top nodes (u, v, a) and tables, for the search for unknown's rivals
    deadline: float        # time.monotonic() by which the match must end


def stop_reason(expansions: int, max_nodes: int, max_search_s: float) -> str:
    """Why a search that was not exhaustive stopped: its node budget or its time limit."""
    return f'stopped after {expansions} node expansions' if expansions >= max_nodes \
        else f'stopped at the {max_search_s:g} s search limit'


SETTLED = ('the search ended once no place it had not scored could make the answer confident: the hypotheses are '
           'those found by then')


def warm_up() -> None:
    """Compile (or load from numba's cache) every kernel bnb uses."""
    warm_up_search()
    warm_up_refine()
    warm_up_pixel_kernels()


class BranchAndBoundMatcher(Matcher):
    name = 'bnb'
    min_score = 0.0

    def __init__(self, occupancy_map: OccupancyMap, options: Optional[BranchAndBoundOptions] = None,
                 slice_expansions: int = 5000):
        super().__init__(occupancy_map)
        self.options = options or BranchAndBoundOptions()
        self.hypotheses, self.distinct_m = self.options.hypotheses, self.options.distinct_m
        self.distinct_angle = self.options.distinct_angle
        self.stack = PrecomputationGridStack(occupancy_map, self.options)
        self.searcher = ThreadedSearch(slice_expansions)
        self.peaks = PeakRefiner(self.stack, occupancy_map, self.options)
        self._last_tops = None     # (scan key, its top nodes and tables): see tree_search
        self._paused = None        # (scan key, search.Paused): a probe's search, see tree_search
        # Called with each match's distinct peaks (their leaf scores), their refined fits and the
        # ranked candidates: what an experiment on the band or the refinement measures
        # (benchmarks/experiments/), read without changing the search. None: nothing called.
        self.on_peaks: Optional[Callable[[list[float], list[float], list[Candidate]], None]] = None
        warm_up()

    def judge_exhaustive(self, candidates, stats=None):
        """See verdict.judge; judged for the band the search covered (SearchStats.band_allowance)."""
        opt = self.options
        if stats is not None and stats.band_allowance != opt.band_allowance:
            opt = dataclasses.replace(opt, band_allowance=stats.band_allowance)
        return judge(candidates, opt)

    def prepare(self, points: np.ndarray) -> np.ndarray:
        """One point per cell (voxel filter), at most max_points of them, evenly chosen."""
        pts = voxel_filter(points[np.hypot(points[:, 0], points[:, 1]) <= self.options.max_range], self.map.resolution)
        if len(pts) > self.options.max_points:
            pts = pts[np.linspace(0, len(pts) - 1, self.options.max_points).astype(int)]
        return pts

    def tables(self, pts: np.ndarray, d0: float, n_angles: int) -> ScanTables:
        """What the kernels read for this scan: per level h, the points' cell offsets at
        the middle angle of each node's angles (rows row_start[h] + a >> h), and where in
        the flat planes the plane each point reads (grid_ids) starts."""
        res = self.map.resolution
        ranges = np.hypot(pts[:, 0], pts[:, 1])
        gid = self.stack.grid_ids(ranges, max(float(ranges.max()), 1e-9))
        thetas, row_start = [], []
        for h in range(self.options.levels):
            row_start.append(sum(len(t) for t in thetas))
            size = 2 ** h
            thetas.append((np.arange(0, n_angles, size) + (size - 1) / 2.0) * d0)
        du, dv = offset_tables(np.concatenate(thetas), pts[:, 0] / res, pts[:, 1] / res)   # (rows, points)
        return ScanTables(self.stack.offsets[gid], du, dv, np.array(row_start, np.int64),
                          int(self.options.unknown_credit * 255 * len(pts)))

    def bounds(self, level: int, tu, tv, ta, pts, d0) -> np.ndarray:
        """Bounds (level > 0) or exact scores (level 0) of nodes (tu, tv, ta), in [0, 1]."""
        n_angles = int(round(2 * math.pi / d0))
        raw = node_bounds(self.stack.planes, self.tables(pts, d0, n_angles), np.asarray(tu, np.int64),
                          np.asarray(tv, np.int64), np.asarray(ta, np.int64), level)
        return raw / (255.0 * len(pts))

    def match(self, points: ScanPoints, options: MatchOptions, progress: Optional[ProgressFn] = None) -> Match:
        tree = self.tree_search(points, options, progress)
        if tree is None:
            return Match([])
        # 3. Peaks, refined, checked for free space, ranked.
        candidates = self.refine_peaks(tree.run.leaves, tree.pts, tree.d0, points)
        # 4. A confident answer on a map with unknown cells: the places the map cannot rule out.
        if options.unknown_rivals and self.stack.has_unknown and candidates and not tree.stopped and \
                not tree.run.settled and self.judge_exhaustive(candidates, tree.stats).success:
            tree = self.unknown_rivals(tree, options, points, progress)
            candidates = self.refine_peaks(tree.run.leaves, tree.pts, tree.d0, points)
        if progress:
            progress(1.0, candidates[0].score if candidates else 0.0)
        settled = SETTLED if tree.run.settled else ''
        return Match(candidates, tree.stats, tree.stopped, settled)

    def unknown_rivals(self, tree: 'TreeSearch', options: MatchOptions, points: ScanPoints,
                       progress: Optional[ProgressFn]) -> 'TreeSearch':
        """The search again, over the optimistic planes (unknown cells a beam can reach may
        hide a wall, for at most bnb.unknown_credit of the scan: kernels), pruned from the
        start by the best leaf's band: every place whose optimistic score reaches it, so
        that a place whose walls the map lacks is never pruned for them and stays a rival
        (verdict.rival_rank). Run only after a confident answer (any other is not made
        confident by a rival) and within what is left of the match's node budget and time;
        it ends as soon as the places found so far, refined and checked for free space,
        make the answer not confident (a rival is proved: the rest cannot make it confident
        again, only add rivals), or once every place the verdict weighs as a rival is found
        (peaks.PeakRefiner.rivals_settled). Returns the tree with both searches' leaves."""
        first = tree.run
        tu, tv, ta, tables = tree.tops
        top = self.options.levels - 1
        bounds = self.searcher.node_bounds(self.stack.planes, tables, tu, tv, ta, top)
        evidence = int(first.leaves[:, 4].max())
        max_nodes = options.max_nodes or self.options.max_nodes
        left = max(1, max_nodes - int(first.per_level.sum()))

        slices = [0]

        def rival_proved(leaves: np.ndarray, pending: int) -> bool:
            # refined for a rival after slices 1, 2, 4, 8, ... (a found rival ends it soon, and few
            # refinements when none is), its rivals checked for all found every 4th slice
            slices[0] += 1
            power_of_two = not slices[0] & (slices[0] - 1)
            if slices[0] % 4 and not power_of_two:
                return False
            both = kept_leaves([leaves, first.leaves], tree.space, evidence, len(tree.pts))
            if self.peaks.rivals_settled(both, tree.d0, len(tree.pts), pending):
                return True
            return power_of_two and not self.judge_exhaustive(self.refine_peaks(both, tree.pts, tree.d0, points),
                                                              tree.stats).success

        # the progress reported goes on from where the first search left it (a cancel stops it too)
        report = (lambda fraction, best: progress(0.95, best)) if progress else None
        start = time.perf_counter()
        run = self.searcher.run(SearchInput(self.stack.planes, tables, self.stack.free),
                                SearchStart(tree.space, np.stack([tu, tv, ta, bounds], axis=1).astype(np.int64), top,
                                            evidence),
                                RunLimits(left, tree.deadline, report), rival_proved)
        expansions = int(first.per_level.sum() + run.per_level.sum())
        stopped = '' if run.exact or run.settled else \
            f'confident on what the map knows, but the search for a rival on its unknown cells ' \
            f'{stop_reason(expansions, max_nodes, options.max_search_s)}'
        # a pose both searches kept once, with its optimistic score (an exhaustive second search
        # holds every leaf of the first: its evidence reaches the band)
        leaves = kept_leaves([run.leaves, first.leaves], tree.space, evidence, len(tree.pts))
        stats = dataclasses.replace(tree.stats, exact=run.exact, leaves=len(leaves), expansions=expansions,
                                    per_level=tuple((first.per_level + run.per_level).tolist()),
                                    search_s=tree.stats.search_s + time.perf_counter() - start)
        return tree._replace(run=first._replace(leaves=leaves, per_level=first.per_level + run.per_level,
                                                exact=run.exact), stats=stats, stopped=stopped)

    def tree_stats(self, points: ScanPoints, options: MatchOptions) -> Optional[SearchStats]:
        """The statistics of a search within `options`' limits, with no refinement and no
        verdict (its best leaf: how well the map can explain the scan, cheaply; a map set's
        rounds); None when there is nothing to search."""
        tree = self.tree_search(points, options, None)
        return tree.stats if tree is not None else None

    def top_nodes(self, pts: np.ndarray, region: Optional[SearchRegion]) -> tuple:
        """1. The leaf angle step, and the top-level nodes on blocks that hold a free cell and
        meet the region: (leaf angles, the search space, their u, v, angle index)."""
        step = 2 ** (self.options.levels - 1)
        n_angles = self.leaf_angles(pts)
        gu, gv, ga = np.meshgrid(np.arange(0, self.map.width, step), np.arange(0, self.map.height, step),
                                 np.arange(0, n_angles, step), indexing='ij')
        tu, tv, ta = gu.ravel(), gv.ravel(), ga.ravel()
        space = self.search_space(n_angles, region)
        keep = self.stack.free_block(self.options.levels - 1, tu, tv) & region_mask(space, tu, tv, ta,
                                                                                   self.options.levels - 1)
        return n_angles, space, tu[keep], tv[keep], ta[keep]

    def tree_search(self, points: ScanPoints, options: MatchOptions,
                    progress: Optional[ProgressFn]) -> Optional['TreeSearch']:
        """Steps 1 and 2 of a match: the top-level nodes and the branch and bound; None when
        the scan has too few points or the search space no free block."""
        opt = self.options
        deadline = time.monotonic() + options.max_search_s - options.spent_s
        max_nodes = options.max_nodes or opt.max_nodes
        pts = self.prepare(points.points)
        if len(pts) < 3:
            return None
        top = opt.levels - 1
        key = (pts.tobytes(), options.region)
        last = self._last_tops
        if last is not None and last[0] == key:
            n_angles, space, tu, tv, ta, tables, bounds = last[1]
        else:
            n_angles, space, tu, tv, ta = self.top_nodes(pts, options.region)
            if len(tu) == 0:
                return None
            tables = self.tables(pts, 2 * math.pi / n_angles, n_angles)
            bounds = self.searcher.node_bounds(self.stack.evidence_planes, tables, tu, tv, ta, top)
            # one scan's top nodes and tables kept: a map set searches each map several times
            # with one scan (core.map_set), and they take a few ms to build on a large map
            self._last_tops = (key, (n_angles, space, tu, tv, ta, tables, bounds))
        d0 = 2 * math.pi / n_angles
        # 2. Branch and bound down to the band below the best leaf (verdict.searched_keep).
        search_start = time.perf_counter()
        resume = self.resume_rule(space, pts, d0, points)
        # a search of this scan stopped at a smaller explicit budget (a map set's probe) goes on
        paused, self._paused = self._paused, None
        paused = paused[1] if paused is not None and paused[0] == key and paused[1].expanded < max_nodes else None
        run = self.searcher.run(SearchInput(self.stack.evidence_planes, tables, self.stack.free),
                                SearchStart(space, np.stack([tu, tv, ta, bounds], axis=1).astype(np.int64), top,
                                            int(options.incumbent * 255 * len(pts)), paused),
                                RunLimits(max_nodes, deadline, progress), self.settled_check(pts, d0, points), resume)
        if run.paused is not None and options.max_nodes:
            self._paused = (key, run.paused)
        search_s = time.perf_counter() - search_start
        scores = run.leaves[:, 4] / (255.0 * len(pts))      # evidence
        expansions = int(run.per_level.sum())
        stopped = '' if run.exact or run.settled else stop_reason(expansions, max_nodes, options.max_search_s)
        stats = SearchStats(exact=run.exact, angles=n_angles, points=len(pts), leaves=len(scores),
                            expansions=expansions, per_level=tuple(run.per_level.tolist()), top_nodes=len(tu),
                            threads=search_threads(), best_leaf=float(scores.max()) if len(scores) else 0.0,
                            search_s=search_s, settled=run.settled,
                            band_allowance=1.0 if run.resumed else opt.band_allowance,
                            top_in_band=top_in_band(bounds, resume.space if run.resumed else space, run.leaves,
                                                    len(pts)))
        return TreeSearch(pts, d0, run, stats, stopped, resume.space if run.resumed else space, (tu, tv, ta, tables),
                          deadline)

    def resume_rule(self, space: SearchSpace, pts, d0, points: ScanPoints) -> Optional[Resume]:
        """See early_end.resume_rule."""
        return resume_rule(self.refine_peaks, self.options, space, pts, d0, points)

    def settled_check(self, pts, d0, points: ScanPoints) -> Optional[SettledFn]:
        """See early_end.settled_check."""
        return settled_check(self.refine_peaks, self.options, pts, d0, points)

    def fit_at(self, points: ScanPoints, laser_pose: Rigid2D) -> tuple[float, float, Rigid2D]:
        """How well the map explains the scan at a laser pose, refined within about a cell
        (a tracked pose is never exact): (field score, share of beams through mapped walls,
        the refined pose). The same two measures the search's hypotheses are ranked by."""
        pts = self.prepare(points.points)
        if len(pts) < 3:
            return 0.0, 0.0, laser_pose
        frame = self.map.frame
        u, v, yaw, score = refine(self.stack.field, *frame.world_pose_to_pixel(laser_pose), pts, self.map.resolution)
        through = see_through_fractions(self.stack.occupied, np.array([[u, v, yaw]]), points, self.map.resolution,
                                        self.options)[0]
        return float(score), float(through), frame.pixel_pose_to_world(u, v, yaw)

    def explained(self, score: float) -> float:
        """See base.Tracker (verdict.explained_share)."""
        return explained_share(score)

    def lead_needed(self, score: float) -> float:
        """See base.Tracker (verdict.needed_lead)."""
        return needed_lead(explained_share(score), self.options)

    def leaf_angles(self, pts: np.ndarray) -> int:
        """How many leaf headings the search has for these (prepared) points: steps of at
        most d0 = acos(1 - res^2 / 2 r_max^2), a whole number of top-level nodes' worth."""
        res = self.map.resolution
        r_max = max(float(np.hypot(pts[:, 0], pts[:, 1]).max(initial=0.0)), 3 * res)
        step = 2 ** (self.options.levels - 1)
        return int(math.ceil(2 * math.pi / math.acos(1 - res ** 2 / (2 * r_max ** 2)) / step)) * step

    def search_resolution(self, points: ScanPoints, angle_step_deg: float) -> tuple[float, float]:
        """A cell and the leaf angle step for this scan (see base.Matcher)."""
        return self.map.resolution, 2 * math.pi / self.leaf_angles(self.prepare(points.points))

    def search_space(self, n_angles: int, region: Optional[SearchRegion]) -> SearchSpace:
        """The search's bounds: the map, the leaf angles, and the prior (in pixels and angle steps)."""
        u = v = a = 0.0
        r = w = -1.0
        if region is not None:
            u, v, yaw = self.map.frame.world_pose_to_pixel(region.center)
            d0 = 2 * math.pi / n_angles
            if region.radius_m > 0:
                r = region.radius_m / self.map.resolution
            if 0 < region.yaw_tolerance < math.pi:
                a, w = (yaw / d0) % n_angles, region.yaw_tolerance / d0
        opt = self.options
        return SearchSpace(self.map.width, self.map.height, n_angles, opt.keep_ratio, opt.min_confidence,
                           opt.band_allowance, confident_fit(opt.min_confidence), 0.0, u, v, r, a, w)

    def refine_peaks(self, leaves: np.ndarray, pts, d0, points: ScanPoints) -> list[Candidate]:
        """The distinct hypotheses among the leaves (peaks.PeakRefiner), handed to on_peaks."""
        peaks, fits, out = self.peaks.refine(leaves, pts, d0, points)
        if self.on_peaks is not None:
            self.on_peaks(peaks, fits, out)
        return out
