"""The pipeline: scan -> points -> matcher (distinct hypotheses) -> verdict -> base pose.

`Localizer` holds one map and the matchers built for it, each once: the server's are
prepared with the map (a request never builds one), the CLI's and the benchmark's on first
use. The ROS server, the CLI and the benchmark all call `Localizer.localize`.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from .limits import check_angle_step  # the server's and the request's check too
from .map_io import OccupancyMap
from .matchers import (
    TRACKER_METHOD,
    BranchAndBoundOptions,
    MatchOptions,
    MethodError,
    Tracker,
    make_matcher,
    resolve_method,
)
from .matchers.base import ProgressFn
from .matchers.mirror import mirror_verdict
from .matchers.verify import RawVerdict, check_options, scaled, verify
from .mount import MountError
from .outcome import Outcome
from .scan import Scan, ScanPoints, require_shape, scan_to_points
from .search_region import SearchRegion
from .transform import Rigid2D, covariance_of_composition


@dataclass
class LocalizerConfig:
    """Every knob of the pipeline, documented once; ROS parameters and CLI flags fill it."""
    method: str = 'bnb'                    # matcher name, see matchers.method_names()
    angle_step_deg: float = 5.0            # Δα of the rotated-template matcher
    closing_kernel: int = 3                # morphological closing of the local map's obstacles, pixels (0 = off)
    # Fixed covariance of the thesis matchers (thesis §3.1); defaults are AMCL's initial_cov_{xx,yy,aa}.
    covariance_xy: float = 0.25            # m^2
    covariance_yaw: float = 0.0685         # rad^2 ((15 deg)^2)
    base_T_laser: Rigid2D = field(default_factory=Rigid2D)   # laser mounting on the robot base
    bnb: BranchAndBoundOptions = field(default_factory=BranchAndBoundOptions)
    # Seconds a search may take before it answers `search incomplete` with what it explored
    # (the server sets a few seconds: a goal must end; the CLI and benchmark: no limit).
    max_search_s: float = math.inf
    # Judge a thesis matcher's hypotheses with bnb's verdict and check the rest of the map
    # for a rival (matchers/verify.py); False: its own verdict, as the thesis reported it.
    verify: bool = True
    # A confident answer whose scan's mirror image fits the map better is not a success (the
    # beams read the wrong way round: matchers/mirror.py). Off: the thesis's single search.
    mirror_check: bool = True


@dataclass(frozen=True)
class SearchLimits:
    """What bounds one search beyond the configuration: where (`region`, of the robot base:
    every answer lies in it), from when its time limit (max_search_s) counts (`t0`, a
    time.perf_counter(); None: the call), and for bnb the band and the work: `incumbent`, a
    score a place elsewhere is known to reach (another map of a set: only the band below it
    is searched, so a map without a rival is ruled out quickly), and `max_nodes`, the node
    budget (0: its option's). A map set's goal gives each map's search its own start, so
    that one limit holds for the goal, not one per map."""
    region: Optional[SearchRegion] = None
    t0: Optional[float] = None
    incumbent: float = 0.0
    max_nodes: int = 0


# How far, in the search's resolution (a cell, a leaf heading step), a refinement may move a
# candidate out of the prior as searched and still be moved onto the prior (Localizer.kept):
# the refinement starts at a leaf inside it and wanders a few (0.47 deg, 2.3 steps, measured).
REFINE_REACH = 4.0


class NonFinitePose(ValueError):
    """A result would carry a pose with a NaN or infinite coordinate: refused at the last step,
    whatever path made it (a bad mounting, a degenerate match)."""


def require_finite(pose: Optional[Rigid2D], what: str) -> Optional[Rigid2D]:
    if pose is not None and not pose.is_finite():
        raise NonFinitePose(f'{what} is not finite: {pose}')
    return pose


@dataclass
class Hypothesis:
    pose: Rigid2D          # robot base in the map frame
    score: float
    map: str = ''          # the map it is on, in a map set (core.map_set); '' with one map

    def __post_init__(self):
        require_finite(self.pose, 'a hypothesis pose')


@dataclass
class LocalizationResult:
    outcome: Outcome
    message: str
    method: str
    pose: Optional[Rigid2D] = None          # best hypothesis (base in map frame)
    score: float = float('nan')
    confidence: float = 0.0
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))   # x, y, yaw
    hypotheses: list = field(default_factory=list)   # Hypothesis, best first (after motion: see core.motion)
    time_s: float = 0.0
    dropped: dict = field(default_factory=dict)
    search_stats: Any = None   # what the matcher's search did (bnb: SearchStats), for diagnostics
    region: Optional[SearchRegion] = None   # the search prior as searched (widened to the search's resolution;
                                            # the poses lie in the prior as given)
    raw: Optional[RawVerdict] = None        # a checked thesis matcher's own verdict (its pose: the base's)
    map: str = ''                           # the map the pose is on, in a map set (core.map_set)

    def __setattr__(self, name, value):
        # the one door every pose goes through, set at construction or after: never NaN or inf
        if name == 'pose':
            require_finite(value, 'the result pose')
        elif name == 'hypotheses':
            for h in value:
                require_finite(h.pose, 'a hypothesis pose')
        super().__setattr__(name, value)

    @property
    def success(self) -> bool:
        return self.outcome == Outcome.LOCALIZED


class Localizer:
    """`prepared`: the methods built now, with the map, and the only ones served - a request
    naming another gets a MethodError saying so, instead of a precomputation it cannot
    cancel, time or bound inside the request (the server: its `methods` parameter). None
    (the CLI, the benchmark): each matcher is built on first use."""

    def __init__(self, occupancy_map: OccupancyMap, config: Optional[LocalizerConfig] = None,
                 prepared: Optional[tuple] = None):
        self.map = occupancy_map
        self.config = config or LocalizerConfig()
        self._matchers = {}
        self._unavailable: dict[str, str] = {}      # prepared method -> why it could not be built
        self._build_on_use = prepared is None
        self._has_obstacles = bool(occupancy_map.occupied.any())   # once per map, not per scan
        for method in prepared or ():
            name = resolve_method(method)
            try:
                self._matchers[name] = make_matcher(name, self.map, self.config.bnb)
            except ValueError as e:     # BudgetError, a MethodError from this OpenCV build
                self._unavailable[name] = f'{name} could not be prepared for this map: {e}'

    @property
    def unavailable(self) -> dict[str, str]:
        """The prepared methods that could not be built, with the reason."""
        return dict(self._unavailable)

    def prepared(self) -> list[str]:
        return sorted(self._matchers)

    def reconfigured(self, config: LocalizerConfig) -> 'Localizer':
        """This map with `config` (a live parameter change), sharing the matchers already
        built - they depend on the map and the bnb options only, which must be unchanged."""
        if config.bnb != self.config.bnb:
            raise ValueError('bnb options change only with a new precomputation (a new Localizer)')
        other = Localizer.__new__(Localizer)
        other.__dict__.update(self.__dict__)
        other.config = config
        return other

    def matcher(self, method: str):
        """The matcher for `method`: built (precomputed for this map) on first use, or, with
        `prepared`, one of those; MethodError for an unknown, unprepared or unbuildable one,
        BudgetError for one whose precomputation would not fit the budget."""
        name = resolve_method(method)
        if name in self._matchers:
            return self._matchers[name]
        if name in self._unavailable:
            raise MethodError(self._unavailable[name])
        if not self._build_on_use:
            raise MethodError(f'{name} is not prepared on this server (prepared: {", ".join(self.prepared())}); '
                              f'add it to the methods parameter and configure again')
        self._matchers[name] = make_matcher(name, self.map, self.config.bnb)
        return self._matchers[name]

    def tracker(self, method: Optional[str] = None) -> Tracker:
        """The matcher that scores a scan at a given pose, for the follower, the watch and
        the map check of a proposing matcher: `method` (default: the configured one) when
        it is a Tracker, otherwise matchers.TRACKER_METHOD (the reason is written there)."""
        matcher = self.matcher(method or self.config.method)
        return matcher if isinstance(matcher, Tracker) else self.matcher(TRACKER_METHOD)

    @staticmethod
    def kept(candidates: list, prior: Optional[SearchRegion], near: Optional[SearchRegion],
             laser_T_base: Rigid2D) -> list:
        """The candidates with a finite pose and score (whatever a matcher made of a
        degenerate input), in the search prior when there is one. A prior is a constraint:
        a candidate outside it but in `near` (the prior as searched, widened by how far a
        refinement wanders) is moved onto the prior's nearest pose - a heading prior tighter
        than the search's resolution, or than the refinement's wander, would otherwise lose
        the very place it names; one farther out (a thesis matcher's peak elsewhere) is dropped."""
        out = [c for c in candidates if all(map(math.isfinite, (*c.laser_pose.as_tuple(), c.score)))]
        if prior is None:
            return out
        base_T_laser = laser_T_base.inverse()
        kept = []
        for c in out:
            base = c.laser_pose * laser_T_base
            if prior.contains(base):
                kept.append(c)
            elif near.contains(base):
                kept.append(dataclasses.replace(c, laser_pose=prior.nearest(base) * base_T_laser))
        return kept

    def search_options(self, matcher, points: ScanPoints, angle_step_deg: Optional[float], base_T_laser: Rigid2D,
                       prior: Optional[SearchRegion]) -> tuple:
        """The match's options for this scan: (options, the prior as searched, that widened by a
        refinement's reach, the note on widening it). A prior tighter than the search's
        resolution holds no leaf: it is searched wider, and the answer says so."""
        if not base_T_laser.is_finite():
            raise MountError(f'the laser mounting on the base must be finite, got {base_T_laser}')
        cfg = self.config
        step = check_angle_step(angle_step_deg or cfg.angle_step_deg)
        searched = near = None
        widened = ''
        if prior is not None:
            resolution = matcher.search_resolution(points, step)
            searched, widened = prior.widened_to(*resolution)
            near = searched.widened_by(REFINE_REACH * resolution[0], REFINE_REACH * resolution[1])
        options = MatchOptions(angle_step_deg=step, closing_kernel=cfg.closing_kernel,
                               region=searched.for_laser(base_T_laser) if searched else None,
                               max_search_s=cfg.max_search_s)
        return options, searched, near, widened

    def probe(self, points: ScanPoints, max_nodes: int, incumbent: float = 0.0, base_T_laser: Optional[Rigid2D] = None,
              region: Optional[SearchRegion] = None) -> tuple[float, bool]:
        """bnb's tree search alone, within `max_nodes` expansions and below `incumbent` (see
        SearchLimits), with no refinement and no verdict: (its best leaf score, whether it
        ended within the budget). How well this map can explain the scan, cheaply - a map
        set's rounds (core.map_set); (0, True) for a map with no obstacles."""
        if not self._has_obstacles:
            return 0.0, True
        tracker = self.matcher(TRACKER_METHOD)
        prior = region if region is not None and region.bounded else None
        options = self.search_options(tracker, points, None, base_T_laser or self.config.base_T_laser, prior)[0]
        stats = tracker.tree_stats(require_shape(points), dataclasses.replace(options, incumbent=incumbent,
                                                                              max_nodes=max_nodes))
        return (stats.best_leaf, stats.exact or stats.settled) if stats is not None else (0.0, True)

    def localize(self, scan: Scan, method: Optional[str] = None, angle_step_deg: Optional[float] = None,
                 progress: Optional[ProgressFn] = None, base_T_laser: Optional[Rigid2D] = None,
                 region: Optional[SearchRegion] = None) -> LocalizationResult:
        """Localize one scan. Raises ScanError for an unusable scan, MethodError for an
        unknown method, ValueError for a bad angle step and CanceledError if `progress` raises
        it; otherwise returns a result, successful or not. `base_T_laser` overrides the
        config's laser mounting; `region` (of the robot base) restricts the search."""
        t0 = time.perf_counter()
        return self.localize_points(scan_to_points(scan), method, angle_step_deg, progress, base_T_laser,
                                    SearchLimits(region, t0))

    def judged(self, matcher, points: ScanPoints, options: MatchOptions, progress: Optional[ProgressFn], t0: float,
               keep: tuple) -> tuple:
        """The matcher's search, its hypotheses kept in the prior (`keep`: the prior, the
        prior as searched widened by the refinement's reach, laser_T_base; see `kept`) and
        the one verdict on them: a thesis matcher's hypotheses checked on the map by the
        tracker (matchers/verify.py, its own verdict kept as the raw one), and a confident
        answer's mirror image checked (matchers/mirror.py). (found, candidates, verdict, raw)."""
        cfg = self.config
        tracker = self.tracker(matcher.name)
        checking = cfg.verify and matcher is not tracker
        found = matcher.match(points, options, scaled(progress, 0.0, 0.9) if checking else progress)
        candidates = self.kept(found.candidates, *keep)
        # the matcher decided which hypotheses are distinct; the verdict judges them as they are
        verdict = matcher.judge(candidates, found.stopped, found.settled, found.stats)
        raw = None
        if checking and candidates and not found.stopped:     # a stopped search is never a success anyway
            raw = RawVerdict(verdict.outcome, verdict.confidence, verdict.message,
                             candidates[0].laser_pose * keep[2])
            found, verdict = verify(matcher.name, candidates, points, tracker, check_options(
                options, cfg.max_search_s - (time.perf_counter() - t0)), scaled(progress, 0.9, 1.0))
            candidates = self.kept(found.candidates, *keep)
        scored_by_tracker = matcher is tracker or raw is not None
        if verdict.success and cfg.mirror_check and points.beams and scored_by_tracker:
            unbounded = dataclasses.replace(options, region=None)      # the mirror image may fit anywhere
            searched = getattr(found.stats, 'expansions', 0)
            mirror, note = mirror_verdict(tracker, points, candidates[0], check_options(
                unbounded, cfg.max_search_s - (time.perf_counter() - t0)), searched, scaled(progress, 1.0, 1.0))
            verdict = mirror or (dataclasses.replace(verdict, message=f'{verdict.message} ({note})') if note
                                 else verdict)
        return found, candidates, verdict, raw

    def localize_points(self, points: ScanPoints, method: Optional[str] = None,
                        angle_step_deg: Optional[float] = None, progress: Optional[ProgressFn] = None,
                        base_T_laser: Optional[Rigid2D] = None,
                        limits: SearchLimits = SearchLimits()) -> LocalizationResult:
        """`localize` for points already in the laser frame (e.g. a local map cut from the map),
        within `limits` (the prior, the time limit's start, bnb's incumbent and node budget)."""
        cfg = self.config
        t0 = time.perf_counter() if limits.t0 is None else limits.t0
        matcher = self.matcher(method or cfg.method)
        base_T_laser = base_T_laser or cfg.base_T_laser
        region = limits.region
        prior = region if region is not None and region.bounded else None    # every answer lies in it
        options, searched, near, widened = self.search_options(matcher, points, angle_step_deg, base_T_laser, prior)
        laser_T_base = base_T_laser.inverse()
        # the time limit counts from t0 (a map set's goal: from its start, shared by every map)
        options = dataclasses.replace(options, incumbent=limits.incumbent, max_nodes=limits.max_nodes,
                                      spent_s=time.perf_counter() - t0)
        if not self._has_obstacles:
            return LocalizationResult(Outcome.NO_MATCH, f'the map {self.map.source} has no obstacles (no occupied '
                                                        f'cell) to match a scan against', matcher.name,
                                      time_s=time.perf_counter() - t0, dropped=points.dropped)
        found, candidates, verdict, raw = self.judged(matcher, require_shape(points), options, progress, t0,
                                                      (prior, near, laser_T_base))
        hyps = [Hypothesis(c.laser_pose * laser_T_base, c.score) for c in candidates]
        message = f'{verdict.message}; {widened}' if widened else verdict.message
        result = LocalizationResult(verdict.outcome, message, matcher.name, confidence=verdict.confidence,
                                    hypotheses=hyps, time_s=time.perf_counter() - t0, dropped=points.dropped,
                                    covariance=np.diag([cfg.covariance_xy, cfg.covariance_xy, cfg.covariance_yaw]),
                                    search_stats=found.stats, region=searched, raw=raw)
        if hyps:
            result.pose, result.score = hyps[0].pose, hyps[0].score
            if candidates[0].covariance is not None:
                result.covariance = covariance_of_composition(candidates[0].laser_pose, candidates[0].covariance,
                                                              laser_T_base)
        return result
