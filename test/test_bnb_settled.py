"""The search's settled end (bnb.settle_slack): it stops once no place it has not scored
can make its answer confident, and then never answers with a success."""
from __future__ import annotations

import numpy as np
import pytest

from global_loc.core.localizer import Localizer, LocalizerConfig
from global_loc.core.matchers.base import Candidate
from global_loc.core.matchers.bnb import BranchAndBoundMatcher, BranchAndBoundOptions
from global_loc.core.matchers.bnb.verdict import judge, unscored_could_be_confident
from global_loc.core.outcome import Outcome
from global_loc.core.scan import Scan
from global_loc.core.transform import Rigid2D

OPTIONS = BranchAndBoundOptions()
ANGLES = np.linspace(-2.35, 2.35, 541)


def scan_of(ranges) -> Scan:
    return Scan(angle_min=float(ANGLES[0]), angle_increment=float(ANGLES[1] - ANGLES[0]), range_min=0.05,
                range_max=20.0, ranges=np.asarray(ranges, float))


def candidate(x: float, fit: float, see_through: float) -> Candidate:
    return Candidate(Rigid2D(x, 0.0, 0.0), fit * (1.0 - see_through), explained=fit, see_through=see_through)


def test_no_unscored_place_the_rule_rules_out_can_make_an_answer_confident():
    """Random hypothesis lists the verdict does not call confident, and a place the search
    has not scored (field score at most the bound) added to them: whenever
    unscored_could_be_confident says no, the verdict with that place is not `localized`
    either - at every field score up to the bound, with or without walls in its way."""
    rng = np.random.default_rng(0)
    checked = 0
    for _ in range(4000):
        found = [candidate(3.0 * k, rng.uniform(0.05, 1.0), rng.uniform(0, 0.6) * (rng.random() < 0.5))
                 for k in range(int(rng.integers(1, 6)))]
        found.sort(key=lambda c: -c.score)
        if judge(found, OPTIONS).success:
            continue
        bound = rng.uniform(0.0, 1.05)
        best_fit = max(c.explained for c in found)
        if unscored_could_be_confident(bound, best_fit, OPTIONS):
            continue
        for fit in np.linspace(0.0, min(bound, 1.0), 12):
            place = candidate(-50.0, fit, 0.0)
            with_it = sorted(found + [place], key=lambda c: -c.score)
            assert not judge(with_it, OPTIONS).success, (bound, fit, [(c.explained, c.see_through) for c in found])
            checked += 1
    assert checked > 5000


def test_the_rule_is_monotone_in_the_bound():
    """A search may rely on it only if a lower bound never makes a place more able to win."""
    for best in np.linspace(0.05, 1.0, 40):
        could = [unscored_could_be_confident(b, best, OPTIONS) for b in np.linspace(0.0, 1.1, 221)]
        assert could == sorted(could)      # False ... False True ... True
    assert not unscored_could_be_confident(0.44, 0.1, OPTIONS)     # explains too little to be confident
    assert unscored_could_be_confident(0.9, 0.8, OPTIONS)          # leads 0.8 by more than 5%


@pytest.mark.parametrize('ranges, outcome', [
    # a wavy round room: nothing like it in the office; many places fit it in part
    (3.0 + 0.3 * np.sin(7 * ANGLES), Outcome.AMBIGUOUS),
    # returns scattered at random: the map explains little of them anywhere
    (np.random.default_rng(3).uniform(0.5, 3.0, len(ANGLES)), Outcome.POOR_MATCH),
])
def test_a_search_whose_answer_cannot_become_confident_ends_early(office_map, ranges, outcome):
    """The same scan searched to the end of the band (settle_slack 1) and with the default:
    the same outcome, fewer node expansions, the hypotheses found by then (a full list when
    ambiguous: resolving by motion follows it), and a message that says the search ended early."""
    whole = Localizer(office_map, LocalizerConfig(bnb=BranchAndBoundOptions(settle_slack=1.0)))
    default = Localizer(office_map)
    a, b = (loc.localize(scan_of(ranges), method='bnb') for loc in (whole, default))
    assert a.outcome == b.outcome == outcome and not b.success
    assert not a.search_stats.settled and b.search_stats.settled
    assert b.search_stats.expansions < a.search_stats.expansions
    assert b.hypotheses and (outcome != Outcome.AMBIGUOUS or len(b.hypotheses) == OPTIONS.hypotheses)
    assert 'the search ended once no place it had not scored could make the answer confident' in b.message


def test_a_settled_search_is_never_judged_a_success(office_map):
    """The guard in Matcher.judge: hypotheses judged confident from a search that ended
    early (as if the localizer had dropped a rival) make `search incomplete`, not a success."""
    matcher = BranchAndBoundMatcher(office_map)
    confident = [candidate(0.0, 0.9, 0.0), candidate(5.0, 0.5, 0.0)]
    assert matcher.judge(confident).success
    verdict = matcher.judge(confident, settled='ended early')
    assert verdict.outcome == Outcome.SEARCH_INCOMPLETE and not verdict.success
