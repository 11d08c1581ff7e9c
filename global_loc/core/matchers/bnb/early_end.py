"""bnb's two ways to end a search before the whole keep_ratio band is expanded, each
exact about what it gives up: a narrow band resumed with the whole one unless its answer
cannot change (resume_rule), and an early end once no place not yet scored could make
the answer confident (settled_check). Both judge hypotheses made by `refine_peaks`
(the matcher's: leaves, points, leaf angle step, scan -> hypotheses)."""
from __future__ import annotations

from typing import Callable, NamedTuple, Optional

import numpy as np

from ...outcome import Outcome
from ...scan import ScanPoints
from ..base import Candidate
from .kernels import SearchSpace
from .options import BranchAndBoundOptions
from .search import Resume, SettledFn
from .verdict import REFINED_GAIN, explained_share, judge, keep_floor, needed_lead, unscored_could_be_confident

RefineFn = Callable[[np.ndarray, np.ndarray, float, ScanPoints], list[Candidate]]


class SettledJudgment(NamedTuple):
    """settled_check's last judgment of the leaves kept so far."""
    leaves: int        # how many leaves it judged
    settled: bool      # they judge `poor match`, or `ambiguous` with a full list
    fit: float         # the best field score among their hypotheses


def resume_rule(refine_peaks: RefineFn, options: BranchAndBoundOptions, space: SearchSpace, pts, d0,
                points: ScanPoints) -> Optional[Resume]:
    """With a narrow band (band_allowance < 1): the search resumes with the whole
    keep_ratio band unless the narrow band's answer is `localized` and no place below
    it could come within the lead: such a place's leaf scores below the band's floor,
    its refined fit at most REFINED_GAIN above that. A resumed search ends exactly as
    one with the whole band from the start (the test_bnb_resume suite)."""
    if options.band_allowance >= 1.0:
        return None
    norm = 255.0 * len(pts)

    def needed(leaves: np.ndarray) -> bool:
        if len(leaves) == 0:
            return True
        candidates = refine_peaks(leaves, pts, d0, points)
        if not judge(candidates, options).success:
            return True
        best = candidates[0]
        unseen = keep_floor(space, int(leaves[:, 4].max()), len(pts)) / norm + REFINED_GAIN
        lead = needed_lead(explained_share(best.score), options)
        return min(best.score, best.explained) * (1.0 - lead) < unseen
    return Resume(space._replace(band_allowance=1.0), needed)

def settled_check(refine_peaks: RefineFn, options: BranchAndBoundOptions, pts, d0,
                  points: ScanPoints) -> Optional[SettledFn]:
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
    opt = options
    if opt.settle_slack >= 1.0:
        return None
    norm = 255.0 * len(pts)
    last = SettledJudgment(leaves=-1, settled=False, fit=1.0)

    def settled(leaves: np.ndarray, top: int) -> bool:
        nonlocal last
        bound = top / norm + opt.settle_slack
        if len(leaves) == 0 or top > leaves[:, 4].max() or \
                unscored_could_be_confident(bound, leaves[:, 4].max() / norm + opt.settle_slack, opt):
            return False
        would_end = last.settled and not unscored_could_be_confident(bound, last.fit, opt)
        if len(leaves) != last.leaves and (len(leaves) > 1.2 * last.leaves or would_end):
            candidates = refine_peaks(leaves, pts, d0, points)
            outcome = judge(candidates, opt).outcome if candidates else Outcome.NO_MATCH
            last = SettledJudgment(len(leaves), outcome == Outcome.POOR_MATCH or (
                outcome == Outcome.AMBIGUOUS and len(candidates) >= opt.hypotheses),
                max((c.explained for c in candidates), default=1.0))
        return len(leaves) == last.leaves and last.settled and \
            not unscored_could_be_confident(bound, last.fit, opt)
    return settled

