"""One verdict for every method: the hypotheses a thesis matcher proposes (rotated
template, features) are judged the way bnb judges its own before anything is published.

Each proposal is refined and scored on the map with bnb's measures (the share of the scan
the map explains at it, the share of beams that would pass through mapped walls), and the
rest of the map is checked for a rival by bnb's exhaustive search (its bounds, the same
band and time limit): an answer is confident only when bnb's verdict on the proposals and
the rivals together is, *and* its best place is the proposer's own best. The proposer's
own verdict is kept as the raw one (what the thesis reported), so the benchmark shows both.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Optional

from ..outcome import Outcome
from ..scan import ScanPoints
from ..transform import Rigid2D
from .base import Candidate, Match, MatchOptions, ProgressFn, Tracker, Verdict, apart


@dataclass(frozen=True)
class RawVerdict:
    """The proposing matcher's own verdict, before the check (the thesis's numbers)."""
    outcome: Outcome
    confidence: float
    message: str
    pose: Optional[Rigid2D]     # its best hypothesis (the Localizer gives the base pose in the map)

    @property
    def success(self) -> bool:
        return self.outcome == Outcome.LOCALIZED


def refined_on_map(checker: Tracker, candidates: list[Candidate], points: ScanPoints) -> list[Candidate]:
    """Each proposal refined within about a cell and scored as bnb scores its own peaks
    (field score x (1 - see-through share)), in the proposer's order."""
    out = []
    for c in candidates:
        fit, through, pose = checker.fit_at(points, c.laser_pose)
        out.append(Candidate(pose, fit * (1.0 - through), explained=fit, see_through=through))
    return out


def verify(proposer: str, proposals: list[Candidate], points: ScanPoints, checker: Tracker, options: MatchOptions,
           progress: Optional[ProgressFn] = None) -> tuple[Match, Verdict]:
    """The checked hypotheses (the proposals refined and bnb's rivals, distinct, best
    first) and the one verdict on them. `checker`: the map's Tracker (Localizer.tracker)."""
    refined = refined_on_map(checker, proposals, points)
    rivals = checker.match(points, options, progress)
    # where the tracker found the same place, its own peak stands for it: it carries every
    # measure its verdict reads (a rival's unknown cells among them), a refined proposal only two
    found = rivals.candidates
    alone = [r for r in refined if all(apart(r, c, checker.distinct_m, checker.distinct_angle) for c in found)]
    union = checker.distinct(sorted(alone + found, key=lambda c: -c.score))
    verdict = checker.judge(union, rivals.stopped, rivals.settled, rivals.stats)
    checked = Match(union, rivals.stats, rivals.stopped, rivals.settled)
    if not verdict.success:
        return checked, Verdict(verdict.outcome, verdict.confidence, f'{verdict.message} (map check of {proposer})')
    if refined and not apart(refined[0], union[0], checker.distinct_m, checker.distinct_angle):
        return checked, verdict
    return checked, Verdict(Outcome.AMBIGUOUS, 0.0, f'ambiguous: the map explains another place better than '
                                                    f'{proposer}\'s best (map check); see the hypotheses')


def scaled(progress: Optional[ProgressFn], lo: float, hi: float) -> Optional[ProgressFn]:
    """`progress` with its fraction mapped to [lo, hi] (two searches report as one)."""
    if progress is None:
        return None
    return lambda fraction, best: progress(lo + (hi - lo) * fraction, best)


def check_options(options: MatchOptions, remaining_s: float) -> MatchOptions:
    """The check searches within what is left of the request's time limit."""
    return dataclasses.replace(options, max_search_s=max(remaining_s, 0.01))
