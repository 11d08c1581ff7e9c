"""bnb's verdict as a pure function of the hypotheses, the search's statistics and the
options; and the matcher keeps nothing of one search for the next."""
import math

import numpy as np
import pytest

from conftest import small_room
from global_loc.core.matchers import MatchOptions
from global_loc.core.matchers.base import Candidate
from global_loc.core.matchers.bnb import BranchAndBoundMatcher, BranchAndBoundOptions
from global_loc.core.matchers.bnb.search import SearchStats
from global_loc.core.matchers.bnb.verdict import judge
from global_loc.core.outcome import Outcome
from global_loc.core.scan import scan_to_points
from global_loc.core.transform import Rigid2D
from global_loc.sim.raycast import simulate_scan

OPTIONS = BranchAndBoundOptions()


def stats(exact=True):
    return SearchStats(exact=exact, angles=512, points=100, leaves=10, expansions=1000, per_level=(1000,),
                       top_nodes=10, threads=1, best_leaf=0.9)


def place(x, fit, see_through=0.0):
    return Candidate(Rigid2D(x, 0.0, 0.0), fit * (1.0 - see_through), explained=fit, see_through=see_through)


@pytest.mark.parametrize('candidates, exact, outcome, message', [
    ([], True, Outcome.NO_MATCH, 'bnb found no pose on free space'),
    ([place(0, 0.9)], False, Outcome.SEARCH_INCOMPLETE, 'search incomplete: stopped after 400000'),
    ([], False, Outcome.SEARCH_INCOMPLETE, 'search incomplete'),
    ([place(0, 0.9), place(5, 0.8)], True, Outcome.LOCALIZED, 'localized'),
    ([place(0, 0.9)], True, Outcome.LOCALIZED, 'localized'),
    ([place(0, 0.9), place(5, 0.88)], True, Outcome.AMBIGUOUS, 'ambiguous: 1 other place(s) within 5% of the best'),
    ([place(0, 0.4), place(5, 0.2)], True, Outcome.POOR_MATCH, 'poor match: the map explains about 40%'),
    ([place(0, 0.85), place(5, 0.9, see_through=0.3)], True, Outcome.AMBIGUOUS,
     'ambiguous: another place explains the scan as well or better, but 30% of its beams'),
])
def test_verdict(candidates, exact, outcome, message):
    verdict = judge(candidates, stats(exact), OPTIONS)
    assert verdict.outcome == outcome and verdict.message.startswith(message), verdict
    assert verdict.success == (outcome == Outcome.LOCALIZED)
    assert 0.0 <= verdict.confidence <= 1.0


def test_confidence_follows_the_margin_and_min_confidence_is_an_option():
    close = [place(0, 0.9), place(5, 0.86)]       # 4.4% behind: confidence 0.44
    assert judge(close, stats(), OPTIONS).confidence == pytest.approx(0.04 / 0.9 / 0.1)
    assert judge(close, stats(), OPTIONS).outcome == Outcome.AMBIGUOUS
    assert judge(close, stats(), BranchAndBoundOptions(min_confidence=0.4)).outcome == Outcome.LOCALIZED


def test_one_search_leaves_nothing_for_the_next():
    """On one matcher: a search that ends, one stopped by the node budget, the first again:
    each verdict reads its own statistics, and the first answer comes back unchanged."""
    room = small_room()
    matcher = BranchAndBoundMatcher(room, BranchAndBoundOptions(levels=4, max_nodes=3000))
    rng = np.random.default_rng(2)
    distinctive = scan_to_points(simulate_scan(room, Rigid2D(1.0, 2.0, 0.3), 360.0, 360, 4.0, rng=rng))
    glimpse = scan_to_points(simulate_scan(room, Rigid2D(2.0, 1.0, -math.pi / 2), 30.0, 31, 2.0, rng=rng))
    first = matcher.match(distinctive, MatchOptions())
    stopped = matcher.match(glimpse, MatchOptions())
    again = matcher.match(distinctive, MatchOptions())
    assert first.stats.exact and not stopped.stats.exact and again.stats.exact
    assert matcher.judge(stopped.candidates[:5], stopped.stats).outcome == Outcome.SEARCH_INCOMPLETE
    assert matcher.judge(again.candidates[:5], again.stats).outcome == Outcome.LOCALIZED
    assert [(c.laser_pose, c.score) for c in again.candidates] == [(c.laser_pose, c.score) for c in first.candidates]
