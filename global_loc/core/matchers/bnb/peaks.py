"""bnb's hypotheses from the search's leaves: the distinct peaks, refined on the
likelihood field, checked for free space and for what the map cannot rule out (unknown
cells), ranked; the best with its covariance."""
from __future__ import annotations

import numpy as np

from ...map_io import OccupancyMap
from ...scan import ScanPoints
from ..base import Candidate, apart, distinct
from .free_space import clear_returns, on_unknown, see_through_fractions
from .grids import PrecomputationGridStack
from .options import BranchAndBoundOptions
from .refine import PeakBins, PixelPose, bin_maxima, field_samples, landscape_covariance, refine

# How many times the hypotheses' number of places, by optimistic score, are refined for
# the strongest rival the map cannot rule out
RIVAL_PEAKS = 4


class PeakRefiner:
    """Per map: turns a search's leaves into ranked hypotheses."""

    def __init__(self, stack: PrecomputationGridStack, occupancy_map: OccupancyMap, options: BranchAndBoundOptions):
        self.stack = stack
        self.map = occupancy_map
        self.options = options

    def leaf_peaks(self, leaves: np.ndarray, column: int, d0: float, norm: float, count: int) -> list[Candidate]:
        """The `count` best distinct places among the leaves (search_step's rows) by one of
        their scores (column 3: optimistic, 4: evidence): `distinct` on the best leaf of each
        bin half as wide as distinct_m and distinct_angle - two leaves in one bin are never
        two places."""
        opt = self.options
        frame = self.map.frame
        tu, tv, ta, scores = leaves[:, 0], leaves[:, 1], leaves[:, 2], leaves[:, column] / norm
        bins = bin_maxima(leaves, scores, d0, self.map.height,
                          PeakBins(opt.distinct_m / self.map.resolution / 2, opt.distinct_angle / 2))
        return distinct([Candidate(frame.pixel_pose_to_world(float(tu[i]), float(tv[i]), float(ta[i] * d0)),
                                   float(scores[i])) for i in bins],
                        count, opt.distinct_m, opt.distinct_angle)

    def rivals_settled(self, leaves: np.ndarray, d0: float, n_points: int, top: int) -> bool:
        """Whether a search for rivals on unknown cells has found every place `refine`
        weighs as a rival: the RIVAL_PEAKS x hypotheses best distinct places by optimistic
        score among the leaves (search_step's rows on n_points points, some lifted by
        unknown cells), the last of them above `top`, the highest bound still pending (raw).
        A leaf not found yet scores at most `top`: it can neither displace them nor lift a
        peak bin above them, so the rest of the search would leave the hypotheses and the
        verdict as they are (the rest of the band is never refined)."""
        count = RIVAL_PEAKS * self.options.hypotheses
        if not len(leaves) or not (leaves[:, 3] > leaves[:, 4]).any():
            return False
        norm = 255.0 * n_points
        peaks = self.leaf_peaks(leaves, 3, d0, norm, count)
        return len(peaks) == count and top < peaks[-1].score * norm

    def refine(self, leaves: np.ndarray, pts, d0, points: ScanPoints) -> tuple[list, list, list[Candidate]]:
        """The distinct hypotheses among the leaves (search_step's rows; decided here, once,
        in metres): the best places by evidence, and - where unknown cells lift some
        leaves' optimistic scores - the best by optimistic score too, each refined on the
        evidence field and ranked by field score x (1 - see-through share), with its
        optimistic score at the refined pose (a rival the map cannot rule out,
        verdict.judge) and its share of points on unknown cells with nothing mapped in the
        way. At most `hypotheses` of them: the best-ranked, and the strongest such rival. The
        best carries the landscape covariance. Returns (the peaks' leaf scores, their refined
        fits, the hypotheses)."""
        opt = self.options
        frame = self.map.frame
        norm = 255.0 * len(pts)
        peaks = self.leaf_peaks(leaves, 4, d0, norm, opt.hypotheses)
        if len(leaves) and (leaves[:, 3] > leaves[:, 4]).any():
            # the rival is the best by optimistic score x (1 - see-through), known once refined:
            # more places than the list holds, as the best optimistic ones may cross walls
            peaks += [c for c in self.leaf_peaks(leaves, 3, d0, norm, RIVAL_PEAKS * opt.hypotheses)
                      if all(apart(c, p, opt.distinct_m, opt.distinct_angle) for p in peaks)]
        starts = [frame.world_pose_to_pixel(c.laser_pose) for c in peaks]
        refined = np.array([refine(self.stack.field, u, v, yaw, pts, self.map.resolution)
                            for u, v, yaw in starts]).reshape(-1, 4)
        res = self.map.resolution
        optimistic, unknown = self.unknown_scores(refined, pts) if self.stack.has_unknown else \
            (refined[:, 3], [None] * len(refined))
        through = see_through_fractions(self.stack.occupied, refined[:, :3], points, res, opt)
        rank = refined[:, 3] * (1.0 - through)
        poses = [frame.pixel_pose_to_world(*row[:3]) for row in refined]
        order = self.distinct_order(poses, rank)
        if len(order) > opt.hypotheses:
            rival = max(order[1:], key=lambda i: optimistic[i] * (1 - through[i]))
            order = order[:opt.hypotheses] if rival in order[:opt.hypotheses] else \
                order[:opt.hypotheses - 1] + [rival]
        out = [Candidate(poses[i], float(rank[i]), explained=float(refined[i, 3]),
                         see_through=float(through[i]), optimistic=float(optimistic[i]), unknown=unknown[i])
               for i in order]
        if out:
            out[0].covariance = landscape_covariance(self.stack.field, frame, PixelPose(*refined[order[0], :3]),
                                                     pts, opt.sigma_cells)
        return [c.score for c in peaks], [float(f) for f in refined[:, 3]], out

    def distinct_order(self, poses: list, rank: np.ndarray) -> list[int]:
        """The refined poses' (laser poses in the world) indices best first by rank, each
        place once (base.distinct): two peaks from different bins may converge on one place
        when refined (the evidence's and the optimistic list's peak of one place), and two
        poses within one peak bin (half distinct_m and half distinct_angle, leaf_peaks) are
        never two places - one of them kept twice would tie with itself."""
        opt = self.options
        ranked = [Candidate(pose, float(r)) for pose, r in zip(poses, rank, strict=True)]
        index = {id(c): i for i, c in enumerate(ranked)}
        kept = distinct(ranked, len(ranked), opt.distinct_m / 2, opt.distinct_angle / 2)
        return [index[id(c)] for c in kept]

    def unknown_scores(self, refined: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, list[float]]:
        """Per refined pose (rows u, v, yaw, fit): what the map cannot rule out there - a
        return whose beam reaches it through free and unknown cells may have hit a wall the
        map lacks (the optimistic field there), capped at unknown_credit above the fit as
        the search bounds it - and the share of its points on unknown cells so reached."""
        res, opt = self.map.resolution, self.options
        if len(refined) == 0:
            return np.zeros(0), []
        clear = clear_returns(self.stack.occupied, refined[:, :3], pts, res, opt)
        px, py = pts[:, 0] / res, pts[:, 1] / res
        optimistic = np.where(clear, field_samples(self.stack.optimistic, refined[:, :3], px, py),
                              field_samples(self.stack.field, refined[:, :3], px, py)).mean(axis=1)
        unknown = (clear & on_unknown(self.stack.occupancy, refined[:, :3], pts, res)).mean(axis=1)
        return np.clip(optimistic, refined[:, 3], refined[:, 3] + opt.unknown_credit), [float(u) for u in unknown]
