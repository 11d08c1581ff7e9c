"""Settling an ambiguous place by motion, without ROS. The hypotheses of an ambiguous
answer are followed with odometry; each new scan is scored at each of them (refined
locally: cheap) and the fits add up. Once the robot has moved far enough, the first
hypothesis whose summed fit leads the next by `lead_scans` scans' worth of the margin a
confident single-scan answer needs is the leader. Sums, not means: the views that tell
twins apart may be a few of many (a box seen only while facing one way), and a mean
dilutes them; twins' sums differ only by noise, which grows with the square root of the
number of scans, far slower than a real lead. The leader wins once the scans seen on the
way, fused into one odometry-aligned view and searched over the whole map, agree
(`confirm`); without a leader the fused view alone may settle it, and its close places
no hypothesis follows are taken up (`HypothesisFollower.adopt`). A view that never tells
the places apart (a perfectly symmetric room) never lets one win.

`HypothesisFollower` is that loop over a stream of observations (points, odometry at
the scan's stamp, stamp): the server feeds it scans as they arrive, `localize --follow`
a bag or a CARMEN log, the relocalization benchmark the simulator. It keeps time by the
scans' stamps, never the wall clock, so an offline run is reproducible.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np

from .localizer import Hypothesis, LocalizationResult
from .matchers.base import Tracker
from .outcome import Outcome
from .scan import ScanPoints
from .transform import Rigid2D, pose_correct

# base pose -> (fit, refined base pose)
FitFn = Callable[[Rigid2D], tuple[float, Rigid2D]]


def pose_fitter(tracker: Tracker, points: ScanPoints, base_T_laser: Rigid2D) -> FitFn:
    """How well one scan fits at a robot pose, the one measure tracking and health use:
    the tracker's fit x (1 - share of beams through mapped walls), at the pose refined
    within about a cell (fit_at); with the refined base pose."""
    laser_T_base = base_T_laser.inverse()

    def fit(base: Rigid2D) -> tuple[float, Rigid2D]:
        score, through, laser = tracker.fit_at(points, base * base_T_laser)
        return score * (1.0 - through), laser * laser_T_base
    return fit


@dataclass(frozen=True)
class MotionConfig:
    lead: float = 0.05                   # a confident single-scan margin at a full fit ...
    lead_scans: float = 10.0             # ... this many scans' worth of it is the summed lead a winner needs
    min_travel_m: float = 0.5            # ... after the robot drove this far
    min_turn: float = math.radians(90)   # ... or turned this much
    keep: float = 0.8                    # hypotheses whose mean fit falls below keep x the best are dropped

    @staticmethod
    def for_tracker(tracker: Tracker) -> 'MotionConfig':
        """With the lead a confident single-scan answer of `tracker` needs at a full fit."""
        return MotionConfig(lead=tracker.lead_needed(1.0))


@dataclass
class Track:
    pose: Rigid2D                        # robot base in the map frame
    fits: list = field(default_factory=list)

    @property
    def evidence(self) -> float:
        """The mean fit (for ranking and reporting)."""
        return float(np.mean(self.fits)) if self.fits else 0.0

    @property
    def total(self) -> float:
        return float(np.sum(self.fits))


class MotionResolver:
    def __init__(self, hypotheses: list[Rigid2D], config: MotionConfig = MotionConfig()):
        self.config = config
        self.tracks = [Track(p) for p in hypotheses]
        self.travelled = 0.0
        self.turned = 0.0

    def update(self, motion: Rigid2D, fit: FitFn) -> Optional[Track]:
        """The robot moved by `motion` (base frame, from odometry) and a new scan came:
        move every hypothesis, score the scan there, drop the clearly worse; the winner,
        if one has emerged."""
        self.travelled += math.hypot(motion.x, motion.y)
        self.turned += abs(motion.yaw)
        for track in self.tracks:
            score, track.pose = fit(track.pose * motion)
            track.fits.append(score)
        self.tracks.sort(key=lambda t: -t.total)
        # Hypotheses that slid onto one place (two 1 m apart on a wall both refined onto the
        # right spot) are one: a twin of the leader would otherwise stand as the "next" and
        # hold back a lead over the real rivals. The one with the larger sum stays.
        merged: list[Track] = []
        for track in self.tracks:
            if not any(pose_correct(track.pose, kept.pose) for kept in merged):
                merged.append(track)
        best = merged[0].evidence
        self.tracks = [t for t in merged if t.evidence >= self.config.keep * best]
        return self.winner()

    def moved_enough(self) -> bool:
        """Whether the robot has driven or turned far enough for a winner."""
        return self.travelled >= self.config.min_travel_m or self.turned >= self.config.min_turn

    def winner(self) -> Optional[Track]:
        c = self.config
        if not self.tracks or not self.moved_enough():
            return None
        best = self.tracks[0]
        second = self.tracks[1].total if len(self.tracks) > 1 else 0.0
        return best if best.total > 0 and best.total - second >= c.lead * c.lead_scans * best.evidence else None


def fuse_scans(scans: list[tuple[Rigid2D, ScanPoints]]) -> ScanPoints:
    """Scans taken along the way, as one "scan" seen from the last one's laser pose:
    each scan's points moved by the odometry between its pose and the last (laser poses in
    the odometry frame). A longer view is far more distinctive than any one of them; its
    points are not beams from one origin, so the free-space check does not apply."""
    last = scans[-1][0].inverse()
    points = np.vstack([(last * pose).apply(p.points) for pose, p in scans])
    reach = float(np.hypot(points[:, 0], points[:, 1]).max()) if len(points) else 0.0
    return ScanPoints(points, max(reach, max(p.range_max for _, p in scans)), len(points), beams=False)


def search_fused_view(localizer, tracker: Tracker, seen: list[tuple[Rigid2D, ScanPoints]], base_T_laser: Rigid2D):
    """The scans seen on the way (laser poses in the odometry frame, points), fused into
    one view and searched over the whole map by the tracker (None before two scans)."""
    if len(seen) < 2:
        return None
    return localizer.localize_points(fuse_scans(seen[::3] + seen[-1:]), tracker.name, base_T_laser=base_T_laser)


def close_places(fused, tracker: Tracker) -> list[Rigid2D]:
    """The fused view's best place and every other within the lead a confident answer needs."""
    if not fused.hypotheses:
        return []
    best = fused.hypotheses[0].score
    need = tracker.lead_needed(best)
    return [h.pose for h in fused.hypotheses if h.score >= best * (1.0 - need)]


def confirm(fused, tracker: Tracker, candidate: Optional[Rigid2D] = None, beaten: Sequence[Rigid2D] = ()):
    """The fused view's result when it confirms `candidate` (the leader of the followed
    hypotheses, when there is one), else None: it must be confident and agree with it. A
    leader alone is never enough: a hypothesis can slide along a featureless wall while it
    is followed; the fused view does not depend on the followed hypotheses at all.

    With a leader, the fused view also confirms it when it ranks the leader's place first
    and every place it finds as close is one of `beaten`, the followed hypotheses the
    leader outscored by the lead a winner needs: what tells twins apart (a box seen while
    facing one way) is a small share of a view fused over a whole turn, so the fused view
    alone separates them by less than a single scan's confident margin, while the summed
    fits have already separated exactly those places."""
    if fused is None or fused.pose is None or (candidate is not None and not pose_correct(fused.pose, candidate)):
        return None
    if fused.success:
        return fused
    # Only where the map explains the fused view (its lead needed is the least, 5%) and the
    # leader's sum has had lead_scans scans to build (`beaten` is empty before): a poorly
    # explained view of a few scans (a real log's 1 m between scans) may rank a place first
    # that neither the view nor the sums can vouch for, the true one found by neither.
    if candidate is None or not beaten or fused.outcome != Outcome.AMBIGUOUS or \
            tracker.explained(fused.hypotheses[0].score) < 1.0:
        return None
    close = close_places(fused, tracker)[1:]
    if not all(any(pose_correct(pose, b) for b in beaten) for pose in close):
        return None
    return dataclasses.replace(fused, outcome=Outcome.LOCALIZED, message=(
        f'localized: the fused view ranks it first, and the {len(close)} place(s) as close are hypotheses it led '
        f'while followed'))


SETTLE_PERIOD_S = 1.0     # scan time between two searches of the fused view (a search each: not every scan)


@dataclass(frozen=True)
class Observation:
    points: ScanPoints        # the scan, laser frame
    odometry: Rigid2D         # robot base in the odometry frame at the scan's stamp
    stamp: float              # s, the scan's own stamp
    source: Any = None        # what the caller wants back with the outcome (a LaserScan message, a log index)


@dataclass
class FollowOutcome:
    settled: bool
    result: LocalizationResult     # the winner (LOCALIZED), or the result still ambiguous with the hypotheses left
    travelled_m: float             # by the odometry, until settled or the end
    turned_rad: float
    elapsed_s: float               # scan time from the start scan to the last one used
    scans: int                     # observations used
    last: Optional[Observation]    # the last one used: the poses are the robot's at its stamp (None: none came)


class HypothesisFollower:
    """Follows an ambiguous result's hypotheses from the start scan (its odometry and
    stamp) over the observations given to `observe`; `finish` says how it ended."""

    def __init__(self, result: LocalizationResult, localizer, base_T_laser: Rigid2D, start_odometry: Rigid2D,
                 start_stamp: float, config: Optional[MotionConfig] = None):
        self.result, self.localizer, self.base_T_laser = result, localizer, base_T_laser
        self.tracker = localizer.tracker()     # whatever method answered the single scan (see Localizer.tracker)
        self.resolver = MotionResolver([h.pose for h in result.hypotheses],
                                       config or MotionConfig.for_tracker(self.tracker))
        self.odometry, self.start_stamp = start_odometry, start_stamp
        self.seen: list[tuple[Rigid2D, ScanPoints]] = []    # (laser pose in the odometry frame, points)
        self.checked = -math.inf
        self.winner: Optional[LocalizationResult] = None
        self.last: Optional[Observation] = None

    @property
    def turned(self) -> float:
        return self.resolver.turned

    def observe(self, obs: Observation) -> bool:
        """One more scan: move the hypotheses by the odometry since the last one, score it
        at each; when one leads, the fused view is searched (at most once a second of scan
        time). Whether a winner has settled."""
        motion, self.odometry, self.last = self.odometry.inverse() * obs.odometry, obs.odometry, obs
        self.seen.append((obs.odometry * self.base_T_laser, obs.points))
        leader = self.resolver.update(motion, pose_fitter(self.tracker, obs.points, self.base_T_laser))
        if self.resolver.moved_enough() and obs.stamp - self.checked >= SETTLE_PERIOD_S:
            self.checked = obs.stamp
            fused = search_fused_view(self.localizer, self.tracker, self.seen, self.base_T_laser)
            if leader is not None:
                built = len(self.seen) >= self.resolver.config.lead_scans
                self.winner = confirm(fused, self.tracker, leader.pose,
                                      [t.pose for t in self.resolver.tracks if t is not leader] if built else ())
            if self.winner is None and fused is not None:
                self.adopt(close_places(fused, self.tracker))
        return self.winner is not None

    def adopt(self, places: list[Rigid2D]) -> None:
        """Follow, from now on, each of `places` (robot poses at the last scan) that no
        hypothesis holds, as if it had been followed from the start: it is moved back by the
        odometry to the first scan seen and forward again scan by scan, scored and refined as
        a hypothesis is, so its sum compares with the others'. A single scan keeps a few
        hypotheses; the true place may not be among them (a row of look-alike places), and
        the fused view of the way, which does not depend on them, finds it."""
        tracks = self.resolver.tracks
        laser_T_base = self.base_T_laser.inverse()
        bases = [laser * laser_T_base for laser, _ in self.seen]     # robot base, odometry frame, per scan
        fits = [pose_fitter(self.tracker, points, self.base_T_laser) for _, points in self.seen]
        for place in places:
            if any(pose_correct(place, t.pose) for t in tracks):
                continue
            track = Track(place * self.odometry.inverse() * bases[0])
            for k, fit in enumerate(fits):
                moved = track.pose * (bases[k - 1].inverse() * bases[k]) if k else track.pose
                score, track.pose = fit(moved)
                track.fits.append(score)
            tracks.append(track)

    def follow(self, observations: Iterable[Observation],
               on_step: Optional[Callable[['HypothesisFollower'], None]] = None) -> bool:
        """`observe` each observation until one settles or they end (an iterator may raise
        CanceledError: it goes through), `on_step` after each; whether one settled. Then `finish`."""
        for obs in observations:
            settled = self.observe(obs)
            if on_step is not None:
                on_step(self)
            if settled:
                return True
        return False

    def finish(self, search_fused: bool = True) -> FollowOutcome:
        """The outcome: the winner; or, without one, the scans seen fused and searched once
        more (unless `search_fused` is False: a cancelled request); or still ambiguous."""
        r = self.resolver
        winner, how = self.winner, 'one place led and the scans seen, fused into one view, confirm it'
        if winner is None and search_fused:
            fused = search_fused_view(self.localizer, self.tracker, self.seen, self.base_T_laser)
            winner = confirm(fused, self.tracker)
            how = 'the scans seen, fused into one view, match one place'
        # A followed hypothesis's score is its mean fit over the scans seen (pose_fitter's
        # 0..1 measure), not the matcher's score of the one scan: the message says so.
        hypotheses = [Hypothesis(t.pose, t.evidence) for t in r.tracks]
        moved = f'{r.travelled:.2f} m and {math.degrees(r.turned):.0f} deg'
        elapsed = self.last.stamp - self.start_stamp if self.last is not None else 0.0
        fits = f'scored by their mean fit over the {len(self.seen)} scans followed'
        if winner is None:
            result = dataclasses.replace(
                self.result, hypotheses=hypotheses, pose=hypotheses[0].pose if hypotheses else None,
                message=f'ambiguous after {elapsed:.0f} s of motion ({moved}): {len(hypotheses)} place(s) still '
                        f'match; see the hypotheses ({fits})')
        else:
            others = f' (the other hypotheses {fits})' if len(hypotheses) > 1 else ''
            result = dataclasses.replace(winner, hypotheses=[Hypothesis(winner.pose, winner.score)] + hypotheses[1:],
                                         message=f'localized by motion after {moved}: {how}{others}')
        return FollowOutcome(winner is not None, result, r.travelled, r.turned, elapsed, len(self.seen), self.last)
