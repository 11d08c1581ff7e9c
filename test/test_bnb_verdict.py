"""bnb's verdict as a pure function of the hypotheses and the options; a search stopped
short judged in one place for every matcher; and the matcher keeps nothing of one search
for the next."""
import itertools
import math

import numpy as np
import pytest

from conftest import grid_map, small_room, walled
from global_loc.core.localizer import Localizer, LocalizerConfig
from global_loc.core.matchers import MatchOptions, make_matcher
from global_loc.core.matchers.base import Candidate
from global_loc.core.matchers.bnb import BranchAndBoundMatcher, BranchAndBoundOptions
from global_loc.core.matchers.bnb.verdict import judge
from global_loc.core.outcome import Outcome
from global_loc.core.scan import scan_to_points
from global_loc.core.transform import Rigid2D
from global_loc.sim.raycast import simulate_scan

OPTIONS = BranchAndBoundOptions()


def place(x, fit, see_through=0.0):
    return Candidate(Rigid2D(x, 0.0, 0.0), fit * (1.0 - see_through), explained=fit, see_through=see_through)


@pytest.mark.parametrize('candidates, outcome, message', [
    ([], Outcome.NO_MATCH, 'bnb found no pose on free space'),
    ([place(0, 0.9), place(5, 0.8)], Outcome.LOCALIZED, 'localized'),
    ([place(0, 0.9)], Outcome.LOCALIZED, 'localized'),
    ([place(0, 0.9), place(5, 0.88)], Outcome.AMBIGUOUS, 'ambiguous: 1 other place(s) within 5% of the best'),
    ([place(0, 0.4), place(5, 0.2)], Outcome.POOR_MATCH, 'poor match: the map explains about 40%'),
    ([place(0, 0.85), place(5, 0.9, see_through=0.3)], Outcome.AMBIGUOUS,
     'ambiguous: another place explains the scan as well or better, but 30% of its beams'),
])
def test_verdict(candidates, outcome, message):
    verdict = judge(candidates, OPTIONS)
    assert verdict.outcome == outcome and verdict.message.startswith(message), verdict
    assert verdict.success == (outcome == Outcome.LOCALIZED)
    assert 0.0 <= verdict.confidence <= 1.0


def test_confidence_follows_the_margin_and_min_confidence_is_an_option():
    close = [place(0, 0.9), place(5, 0.86)]       # 4.4% behind: confidence 0.44
    assert judge(close, OPTIONS).confidence == pytest.approx(0.04 / 0.9 / 0.1)
    assert judge(close, OPTIONS).outcome == Outcome.AMBIGUOUS
    assert judge(close, BranchAndBoundOptions(min_confidence=0.4)).outcome == Outcome.LOCALIZED


@pytest.mark.parametrize('method', ['bnb', 'template_ccoeff', 'features_orb'])
@pytest.mark.parametrize('candidates, message', [
    ([place(0, 0.9), place(5, 0.5)], 'search incomplete: stopped after 400000 node expansions; best of what was '
                                     'explored, see the hypotheses'),
    ([], 'search incomplete: stopped after 400000 node expansions; nothing found before it stopped'),
])
def test_a_search_stopped_short_is_judged_in_one_place_for_every_matcher(method, candidates, message):
    """Whatever the matcher and however clear its best, a search that stopped short is
    never a success (a better place may lie in what it did not explore)."""
    verdict = make_matcher(method, small_room()).judge(candidates, 'stopped after 400000 node expansions')
    assert verdict.outcome == Outcome.SEARCH_INCOMPLETE and verdict.confidence == 0.0
    assert verdict.message == message


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
    assert not first.stopped and stopped.stopped.startswith('stopped after') and not again.stopped
    assert matcher.judge(stopped.candidates, stopped.stopped).outcome == Outcome.SEARCH_INCOMPLETE
    assert matcher.judge(again.candidates, again.stopped).outcome == Outcome.LOCALIZED
    assert [(c.laser_pose, c.score) for c in again.candidates] == [(c.laser_pose, c.score) for c in first.candidates]


def test_distinct_hypotheses_are_decided_once_in_metres_and_judged_as_the_matcher_returned_them():
    """A 40 deg glimpse of a straight wall fits all along it: with bnb.distinct_m 0.5 the
    hypotheses are places 0.5 m apart - the verdict judges them and the Localizer presents
    them as the matcher returned them (no second pass merges places closer than 1 m)."""
    room = grid_map(walled(60, 240))      # 12 x 3 m at 5 cm
    scan = simulate_scan(room, Rigid2D(6.0, 1.5, math.pi / 2), 40.0, 81, 2.0, noise_std=0.0)
    localizer = Localizer(room, LocalizerConfig(bnb=BranchAndBoundOptions(distinct_m=0.5)))
    result = localizer.localize(scan)
    found = localizer.matcher('bnb').match(scan_to_points(scan), MatchOptions())
    assert [h.pose.as_tuple() for h in result.hypotheses] == [c.laser_pose.as_tuple() for c in found.candidates]
    assert len(result.hypotheses) == BranchAndBoundOptions().hypotheses
    assert result.outcome == Outcome.AMBIGUOUS and result.message.startswith('ambiguous: 7 other place(s)')
    alike = [(p, q) for p, q in itertools.combinations([h.pose for h in result.hypotheses], 2)
             if p.distance_to(q)[1] < math.radians(20)]
    gaps = [p.distance_to(q)[0] for p, q in alike]
    assert min(gaps) >= 0.5 - 2 * room.resolution     # distinct (refinement moves a peak by about a cell)
    assert min(gaps) < 0.75                           # places closer than 1 m are judged, not merged
