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
from ...outcome import Outcome
from ...pixel_kernels import warm_up as warm_up_pixel_kernels
from ...scan import ScanPoints, voxel_filter
from ...search_region import SearchRegion
from ...transform import Rigid2D
from ..base import Candidate, Match, Matcher, MatchOptions, ProgressFn
from .free_space import see_through_fractions
from .grids import PrecomputationGridStack
from .kernels import ScanTables, SearchSpace, node_bounds, offset_tables, region_mask
from .kernels import warm_up as warm_up_search
from .options import BranchAndBoundOptions
from .refine import bin_maxima, landscape_covariance, refine
from .refine import warm_up as warm_up_refine
from .search import Resume, SearchRun, SearchStats, SettledFn, ThreadedSearch, search_threads, top_in_band
from .verdict import REFINED_GAIN, explained_share, judge, keep_floor, needed_lead, unscored_could_be_confident


class SettledJudgment(NamedTuple):
    """settled_check's last judgment of the leaves kept so far."""
    leaves: int        # how many leaves it judged
    settled: bool      # they judge `poor match`, or `ambiguous` with a full list
    fit: float         # the best field score among their hypotheses


class TreeSearch(NamedTuple):
    """What the branch and bound of one match found, before its peaks are refined."""
    pts: np.ndarray        # the prepared points searched with
    d0: float              # the leaf angle step
    run: SearchRun
    stats: SearchStats
    stopped: str           # why the search stopped early ('' when it did not)


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
        self._last_tops = None     # (scan key, its top nodes and tables): see tree_search
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
        return ScanTables(self.stack.offsets[gid], du, dv, np.array(row_start, np.int64))

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
        leaves = tree.run.leaves
        scores = leaves[:, 3] / (255.0 * len(tree.pts))
        candidates = self.refine_peaks(leaves[:, 0], leaves[:, 1], leaves[:, 2], scores, tree.pts, tree.d0, points)
        if progress:
            progress(1.0, candidates[0].score if candidates else 0.0)
        settled = SETTLED if tree.run.settled else ''
        return Match(candidates, tree.stats, tree.stopped, settled)

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
        deadline = time.monotonic() + options.max_search_s
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
            bounds = self.searcher.node_bounds(self.stack.planes, tables, tu, tv, ta, top)
            # one scan's top nodes and tables kept: a map set searches each map several times
            # with one scan (core.map_set), and they take a few ms to build on a large map
            self._last_tops = (key, (n_angles, space, tu, tv, ta, tables, bounds))
        d0 = 2 * math.pi / n_angles
        # 2. Branch and bound down to the band below the best leaf (verdict.searched_keep).
        search_start = time.perf_counter()
        resume = self.resume_rule(space, pts, d0, points)
        run = self.searcher.run(self.stack.planes, tables, self.stack.free, space,
                                np.stack([tu, tv, ta, bounds], axis=1).astype(np.int64), top, max_nodes, progress,
                                deadline, self.settled_check(pts, d0, points),
                                int(options.incumbent * 255 * len(pts)), resume)
        search_s = time.perf_counter() - search_start
        scores = run.leaves[:, 3] / (255.0 * len(pts))
        expansions = int(run.per_level.sum())
        stopped = '' if run.exact or run.settled else (
            f'stopped after {expansions} node expansions' if expansions >= max_nodes
            else f'stopped at the {options.max_search_s:g} s search limit')
        stats = SearchStats(exact=run.exact, angles=n_angles, points=len(pts), leaves=len(scores),
                            expansions=expansions, per_level=tuple(run.per_level.tolist()), top_nodes=len(tu),
                            threads=search_threads(), best_leaf=float(scores.max()) if len(scores) else 0.0,
                            search_s=search_s, settled=run.settled,
                            band_allowance=1.0 if run.resumed else opt.band_allowance,
                            top_in_band=top_in_band(bounds, resume.space if run.resumed else space, run.leaves,
                                                    len(pts)))
        return TreeSearch(pts, d0, run, stats, stopped)

    def resume_rule(self, space: SearchSpace, pts, d0, points: ScanPoints) -> Optional[Resume]:
        """With a narrow band (band_allowance < 1): the search resumes with the whole
        keep_ratio band unless the narrow band's answer is `localized` and no place below
        it could come within the lead: such a place's leaf scores below the band's floor,
        its refined fit at most REFINED_GAIN above that. A resumed search ends exactly as
        one with the whole band from the start (the test_bnb_resume suite)."""
        if self.options.band_allowance >= 1.0:
            return None
        norm = 255.0 * len(pts)

        def needed(leaves: np.ndarray) -> bool:
            if len(leaves) == 0:
                return True
            candidates = self.refine_peaks(leaves[:, 0], leaves[:, 1], leaves[:, 2], leaves[:, 3] / norm, pts, d0,
                                           points)
            if not judge(candidates, self.options).success:
                return True
            best = candidates[0]
            unseen = keep_floor(space, int(leaves[:, 3].max()), len(pts)) / norm + REFINED_GAIN
            lead = needed_lead(explained_share(best.score), self.options)
            return min(best.score, best.explained) * (1.0 - lead) < unseen
        return Resume(space._replace(band_allowance=1.0), needed)

    def settled_check(self, pts, d0, points: ScanPoints) -> Optional[SettledFn]:
        """The search's early end (search.ThreadedSearch.run's `settled`), True once:
        - the best leaf is known (no pending node bounds above it);
        - no place it has not scored could be judged confident: such a place's leaf scores
          at most the highest pending bound, its refined score at most that plus
          settle_slack (verdict.unscored_could_be_confident);
        - the hypotheses of exactly the leaves kept so far (what match then returns) are
          judged `poor match`, or `ambiguous` with a full list of hypotheses (resolving by
          motion follows an ambiguous answer's list: a shorter one could miss the true place).
        The rest of the band could still add a rival or push a listed one out of a full
        list - change the hypotheses and the confidence number - but not make a place it
        has not scored a confident answer. Refining and judging the leaves costs up to ~20
        ms, a slice's work: only done when the best leaf, refined at most settle_slack
        higher, could end the search, and when the leaves grew by a fifth since or the
        last judgment would now end it. Opt-in (settle_slack < 1): on the benchmark it put a
        worse place first, the true one not yet found, on one ambiguous 60 deg view."""
        opt = self.options
        if opt.settle_slack >= 1.0:
            return None
        norm = 255.0 * len(pts)
        last = SettledJudgment(leaves=-1, settled=False, fit=1.0)

        def settled(leaves: np.ndarray, top: int) -> bool:
            nonlocal last
            bound = top / norm + opt.settle_slack
            if len(leaves) == 0 or top > leaves[:, 3].max() or \
                    unscored_could_be_confident(bound, leaves[:, 3].max() / norm + opt.settle_slack, opt):
                return False
            would_end = last.settled and not unscored_could_be_confident(bound, last.fit, opt)
            if len(leaves) != last.leaves and (len(leaves) > 1.2 * last.leaves or would_end):
                candidates = self.refine_peaks(leaves[:, 0], leaves[:, 1], leaves[:, 2], leaves[:, 3] / norm, pts,
                                               d0, points)
                outcome = judge(candidates, opt).outcome if candidates else Outcome.NO_MATCH
                last = SettledJudgment(len(leaves), outcome == Outcome.POOR_MATCH or (
                    outcome == Outcome.AMBIGUOUS and len(candidates) >= opt.hypotheses),
                    max((c.explained for c in candidates), default=1.0))
            return len(leaves) == last.leaves and last.settled and \
                not unscored_could_be_confident(bound, last.fit, opt)
        return settled

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
                           opt.band_allowance, u, v, r, a, w)

    def refine_peaks(self, tu, tv, ta, scores, pts, d0, points: ScanPoints) -> list[Candidate]:
        """The distinct hypotheses among the leaves (decided here, once, in metres: `distinct`
        on the best leaf of each bin half as wide as distinct_m and distinct_angle - two
        leaves in one bin are never two hypotheses), refined, ranked by field score x (1 -
        see-through share); the best carries the landscape covariance. (7 arguments: the
        leaves as the compiled search returns them, columns apart, the points and the angle step.)"""
        opt = self.options
        frame = self.map.frame
        leaves = [Candidate(frame.pixel_pose_to_world(float(tu[i]), float(tv[i]), float(ta[i] * d0)),
                            float(scores[i]))
                  for i in bin_maxima(tu, tv, ta, scores, d0, self.map.height, opt.distinct_m / self.map.resolution / 2,
                                      opt.distinct_angle / 2)]
        peaks = self.distinct(leaves)
        starts = [frame.world_pose_to_pixel(c.laser_pose) for c in peaks]
        refined = np.array([refine(self.stack.field, u, v, yaw, pts, self.map.resolution)
                            for u, v, yaw in starts]).reshape(-1, 4)
        through = see_through_fractions(self.stack.occupied, refined[:, :3], points, self.map.resolution, opt)
        rank = refined[:, 3] * (1.0 - through)
        order = np.argsort(-rank, kind='stable')
        out = [Candidate(frame.pixel_pose_to_world(*refined[i, :3]), float(rank[i]), explained=float(refined[i, 3]),
                         see_through=float(through[i])) for i in order]
        if out:
            out[0].covariance = landscape_covariance(self.stack.field, frame, *refined[order[0], :3], pts)
        if self.on_peaks is not None:
            self.on_peaks([c.score for c in peaks], [float(f) for f in refined[:, 3]], out)
        return out
