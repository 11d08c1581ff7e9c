"""The one interface every matcher implements.

A matcher is built once per map (precomputation in __init__, reused for every scan)
and aligns one scan's points against that map. `match` returns a `Match`: the distinct
hypotheses (laser poses in the map frame with scores, best first, higher is better; the
matcher decides distinctness, once, in metres: `distinct`), why the search stopped short
if it did, and its statistics. It reports progress through `progress(fraction,
best_score)`, which may raise `CanceledError` to stop it early. `judge` turns exactly those
hypotheses into a Verdict; it reads nothing else, so one matcher serves any number of
threads and callers, and the caller only presents what both returned.

A matcher that can also score a scan at a given pose is a `Tracker`: following hypotheses
with motion, the health watch and the map check of another matcher's answer need exactly
that, and nothing else of it.
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, Callable, Optional, Protocol, runtime_checkable

import numpy as np

from ..limits import check_budget
from ..map_io import OccupancyMap
from ..outcome import Outcome
from ..scan import ScanPoints
from ..search_region import SearchRegion
from ..transform import Rigid2D

ProgressFn = Callable[[float, float], None]


class MethodError(ValueError):
    """An unknown matcher name, or one this OpenCV build cannot provide."""


@dataclass
class Candidate:
    laser_pose: Rigid2D    # laser frame in the map frame
    score: float           # higher is better; scale depends on the matcher
    covariance: Optional[np.ndarray] = None   # 3x3 (x, y, yaw) of laser_pose, when the matcher knows it
    explained: Optional[float] = None      # bnb: fraction of the scan's points the map explains at this pose
    see_through: Optional[float] = None    # bnb: fraction of the beams that would pass through mapped walls
    # bnb: the field score were every unknown cell near the points a wall (what the map cannot
    # rule out: >= explained), and the share of the points on unknown cells or off the map
    optimistic: Optional[float] = None
    unknown: Optional[float] = None


# Distinct hypotheses, for every matcher (bnb declares them as options with these defaults):
# how many, and poses closer than DISTINCT_M metres *and* DISTINCT_ANGLE rad are one place.
HYPOTHESES = 8
DISTINCT_M = 1.0
DISTINCT_ANGLE = math.radians(20.0)


def apart(a: Candidate, b: Candidate, min_distance: float, min_angle: float) -> bool:
    """Whether two candidates are distinct places: min_distance metres *or* min_angle radians apart."""
    d, angle = a.laser_pose.distance_to(b.laser_pose)
    return d >= min_distance or angle >= min_angle


def distinct(candidates: list[Candidate], k: int, min_distance: float, min_angle: float) -> list[Candidate]:
    """Non-maximum suppression in (x, y, yaw): the best k candidates no two of which are
    within min_distance metres *and* min_angle radians of each other. The one place a
    matcher's candidates become distinct hypotheses."""
    kept: list[Candidate] = []
    for c in sorted(candidates, key=lambda c: -c.score):
        if all(apart(c, o, min_distance, min_angle) for o in kept):
            kept.append(c)
            if len(kept) == k:
                break
    return kept


@dataclass
class Match:
    """What one `match` call found."""
    candidates: list[Candidate]   # the distinct hypotheses, best first: what the verdict judges
    stats: Any = None        # the matcher's search statistics (bnb: SearchStats; its verdict reads the band)
    stopped: str = ''        # why the search stopped before it was exhaustive ('' when it was)
    settled: str = ''        # why it ended before searching all it would, its answer settled ('' when it did not)


@dataclass
class Verdict:
    outcome: Outcome
    confidence: float      # 0..1
    message: str

    @property
    def success(self) -> bool:
        return self.outcome == Outcome.LOCALIZED


@dataclass
class MatchOptions:
    """Per-request knobs that every matcher reads (those it does not need it ignores)."""
    angle_step_deg: float = 5.0
    closing_kernel: int = 3                # core.local_grid.close_obstacles
    peaks_per_angle: int = 3
    # Where the laser may be; a matcher may use it to search less (the Localizer drops
    # candidates outside the robot's region in any case).
    region: Optional[SearchRegion] = None
    # Seconds of search after which a matcher stops and answers with what it explored
    # (then never a success: a better place may lie in what it did not reach).
    max_search_s: float = math.inf
    # Seconds of that limit already spent before this match (a map set's earlier maps): one
    # limit holds for the whole goal, and the stop message still names the goal's limit.
    spent_s: float = 0.0
    # A fit (bnb's field score, 0..1) some place is known to reach: an exhaustive search may
    # prune below its band from the start and return only the places that come that close -
    # a check that no place beats a known one costs a fraction of finding the best.
    incumbent: float = 0.0
    # Node expansions an exhaustive search may spend (0: its own budget, bnb.max_nodes): a
    # check beside the search gets less.
    max_nodes: int = 0
    # Whether a confident answer on a map with unknown cells is searched for the places the
    # map cannot rule out (bnb): off for a check that only compares fits (the mirror check).
    unknown_rivals: bool = True


class Matcher(ABC):
    name: str = ''
    # Score at or above which a best candidate counts as a match, on this matcher's scale.
    min_score: float = 0.0
    # Lead over the next distinct place, relative to the best, a success needs: any real
    # lead (1%), not a tie. bnb's verdict has its own rule (verdict.py).
    min_confidence: float = 0.01
    # Distinct hypotheses returned (see `distinct`); bnb sets them from its options.
    hypotheses: int = HYPOTHESES
    distinct_m: float = DISTINCT_M
    distinct_angle: float = DISTINCT_ANGLE

    def __init__(self, occupancy_map: OccupancyMap):
        self.map = occupancy_map

    def search_resolution(self, points: ScanPoints, angle_step_deg: float) -> tuple[float, float]:
        """(metres, radians): the finest position and heading this search tells apart for
        this scan - a search prior tighter than that holds no pose it can return, so the
        Localizer widens it to this. Here: a cell, and the turn that moves the farthest
        point by a cell (the image matchers place the local map to a pixel)."""
        res = self.map.resolution
        farthest = max(float(np.hypot(points.points[:, 0], points.points[:, 1]).max(initial=0.0)), 3 * res)
        return res, math.acos(1 - res ** 2 / (2 * farthest ** 2))

    def check_local_map_budget(self, points: ScanPoints) -> None:
        """BudgetError before drawing the local map (thesis matchers) when it would not fit
        the per-goal budget: a square of side twice the farthest point (capped at the map's
        diagonal, as build_local_grid draws it), drawn, cropped and closed - three images."""
        farthest = float(np.hypot(points.points[:, 0], points.points[:, 1]).max(initial=0.0))
        side = 2 * (math.ceil(min(farthest, self.map.diagonal_m) / self.map.resolution) + 1) + 1
        check_budget(f'{self.name}: a local map of {side} x {side} pixels', 3.0 * side * side,
                     'the scan reaches too far for this map\'s resolution; use bnb')

    def distinct(self, candidates: list[Candidate]) -> list[Candidate]:
        """This matcher's distinct hypotheses among its candidates, best first."""
        return distinct(candidates, self.hypotheses, self.distinct_m, self.distinct_angle)

    def judge(self, candidates: list[Candidate], stopped: str = '', settled: str = '', stats: Any = None) -> Verdict:
        """The verdict on the distinct hypotheses (best first) of a search that stopped
        for `stopped` ('' when it was exhaustive), or ended early because its answer was
        settled (`settled`, Match.settled): the one place a search stopped short is judged
        - never a success, a better place may lie in what it did not explore. `stats`: the
        search's (Match.stats), for a verdict that depends on what was searched (bnb's band)."""
        if stopped:
            seen = 'best of what was explored, see the hypotheses' if candidates else 'nothing found before it stopped'
            return Verdict(Outcome.SEARCH_INCOMPLETE, 0.0, f'search incomplete: {stopped}; {seen}')
        verdict = self.judge_exhaustive(candidates, stats)
        if settled and verdict.success:    # the matcher ends early only on an answer that is not (a guard)
            return Verdict(Outcome.SEARCH_INCOMPLETE, 0.0, f'search incomplete: {settled}, yet the hypotheses are '
                                                            f'judged confident')
        return Verdict(verdict.outcome, verdict.confidence, f'{verdict.message} ({settled})') if settled else verdict

    def judge_exhaustive(self, candidates: list[Candidate], stats: Any = None) -> Verdict:
        """The verdict on an exhaustive search's distinct hypotheses. The thesis matchers:
        confidence = how far the best stands above the next, relative to it; localized
        when the best score is at least min_score *and* the confidence at least
        min_confidence (a best tied with the next - confidence 0, as a scan of one
        point gives - is never a success)."""
        scores = [c.score for c in candidates]
        if not scores:
            return Verdict(Outcome.NO_MATCH, 0.0, f'{self.name} found no match')
        best = scores[0]
        conf = 1.0 if len(scores) == 1 else float(np.clip((best - scores[1]) / best, 0.0, 1.0)) if best > 0 else 0.0
        if best < self.min_score:
            return Verdict(Outcome.POOR_MATCH, conf,
                           f'best score {best:.3f} is below {self.name}\'s minimum {self.min_score}')
        if conf < self.min_confidence:
            return Verdict(Outcome.AMBIGUOUS, conf, f'ambiguous: the next place scores within {100 * conf:.1f}% of '
                                                    f'the best ({self.name} needs {100 * self.min_confidence:.0f}%); '
                                                    f'see the hypotheses')
        return Verdict(Outcome.LOCALIZED, conf, 'localized')

    @abstractmethod
    def match(self, points: ScanPoints, options: MatchOptions, progress: Optional[ProgressFn] = None) -> Match:
        """The distinct hypotheses for the laser pose, best first (possibly none), why the
        search stopped short (if it did) and its statistics."""


@runtime_checkable
class Tracker(Protocol):
    """What following hypotheses with motion (core.motion), the health watch and the map
    check of a proposing matcher (verify.py) need of a matcher, besides `match`, `judge`
    and `distinct`: the fit at a pose, and the lead rule on that fit's scale."""
    name: str
    distinct_m: float
    distinct_angle: float

    def fit_at(self, points: ScanPoints, laser_pose: Rigid2D) -> tuple[float, float, Rigid2D]:
        """How well the map explains the scan at a laser pose, refined within about a cell:
        (fit, share of beams through mapped walls, the refined pose)."""

    def explained(self, score: float) -> float:
        """The share of the scan, 0..1, the map explains at a hypothesis of this score."""

    def lead_needed(self, score: float) -> float:
        """The lead over every other place, relative to the best, a confident answer needs
        when the best scores `score` (lead_needed(1.0): at a full fit)."""

    def match(self, points: ScanPoints, options: MatchOptions, progress: Optional[ProgressFn] = None) -> Match:
        ...

    def judge(self, candidates: list[Candidate], stopped: str = '', settled: str = '', stats: Any = None) -> Verdict:
        ...

    def distinct(self, candidates: list[Candidate]) -> list[Candidate]:
        ...
