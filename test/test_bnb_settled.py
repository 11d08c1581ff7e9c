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
from global_loc.core.scan import Scan, scan_to_points
from global_loc.core.transform import Rigid2D

OPTIONS = BranchAndBoundOptions()
SETTLING = BranchAndBoundOptions(settle_slack=0.05)      # opted into (the default, 1, never ends early)
ANGLES = np.linspace(-2.35, 2.35, 541)


def scan_of(ranges) -> Scan:
    return Scan(angle_min=float(ANGLES[0]), angle_increment=float(ANGLES[1] - ANGLES[0]), range_min=0.05,
                range_max=20.0, ranges=np.asarray(ranges, float))


def candidate(x: float, fit: float, see_through: float) -> Candidate:
    return Candidate(Rigid2D(x, 0.0, 0.0), fit * (1.0 - see_through), explained=fit, see_through=see_through)


@pytest.mark.parametrize('options', [OPTIONS, BranchAndBoundOptions(min_confidence=0.001),
                                     BranchAndBoundOptions(min_confidence=1.0, keep_ratio=0.8),
                                     BranchAndBoundOptions(keep_ratio=0.95, band_allowance=0.0),
                                     BranchAndBoundOptions(band_allowance=0.03)])
def test_no_unscored_place_the_rule_rules_out_can_make_an_answer_confident(options):
    """Random hypothesis lists the verdict does not call confident, and a place the search
    has not scored (field score at most the bound) added to them: whenever
    unscored_could_be_confident says no, the verdict with that place is not `localized`
    either - at every field score up to the bound, with or without walls in its way, for
    any min_confidence and keep_ratio, and where the band is narrowed (band_allowance).
    The place lies within keep_ratio of the best found, as every place the search keeps."""
    rng = np.random.default_rng(0)
    checked = 0
    for _ in range(4000):
        found = [candidate(3.0 * k, rng.uniform(0.05, 1.0), rng.uniform(0, 0.6) * (rng.random() < 0.5))
                 for k in range(int(rng.integers(1, 6)))]
        found.sort(key=lambda c: -c.score)
        if judge(found, options).success:
            continue
        bound = rng.uniform(0.0, 1.05)
        best_fit = max(c.explained for c in found)
        if unscored_could_be_confident(bound, best_fit, options):
            continue
        # the search keeps only places within keep_ratio of its best (below, a place would
        # stand in for the unseen rest of the band and only lower the verdict's rival)
        low, high = options.keep_ratio * best_fit, min(bound, 1.0)
        for fit in np.linspace(low, high, 12) if high >= low else []:
            place = candidate(-50.0, fit, 0.0)
            with_it = sorted(found + [place], key=lambda c: -c.score)
            assert not judge(with_it, options).success, (bound, fit, [(c.explained, c.see_through) for c in found])
            checked += 1
    assert checked > 1000


def test_the_rule_is_monotone_in_the_bound():
    """A search may rely on it only if a lower bound never makes a place more able to win."""
    for best in np.linspace(0.05, 1.0, 40):
        could = [unscored_could_be_confident(b, best, OPTIONS) for b in np.linspace(0.0, 1.1, 221)]
        assert could == sorted(could)      # False ... False True ... True
    assert not unscored_could_be_confident(0.44, 0.1, OPTIONS)     # explains too little to be confident
    assert unscored_could_be_confident(0.9, 0.8, OPTIONS)          # leads 0.8 by more than 5%


@pytest.mark.parametrize('ranges, outcome', [
    # a straight corridor 2.5 m wide, seen to 4 m: the office has many such stretches
    (np.where(1.25 / np.maximum(np.abs(np.sin(ANGLES)), 1e-6) < 4.0,
              1.25 / np.maximum(np.abs(np.sin(ANGLES)), 1e-6), np.inf), Outcome.AMBIGUOUS),
    # returns scattered at random: the map explains little of them anywhere
    (np.random.default_rng(3).uniform(0.5, 3.0, len(ANGLES)), Outcome.POOR_MATCH),
])
def test_a_search_whose_answer_cannot_become_confident_ends_early(office_map, ranges, outcome):
    """The same scan searched to the end of the band (settle_slack 1, the default) and with 0.05:
    the same outcome, fewer node expansions, the hypotheses found by then (a full list when
    ambiguous: resolving by motion follows it), and a message that says the search ended early."""
    whole = Localizer(office_map, LocalizerConfig(bnb=BranchAndBoundOptions(settle_slack=1.0)))
    settling = Localizer(office_map, LocalizerConfig(bnb=SETTLING))
    a, b = (loc.localize(scan_of(ranges), method='bnb') for loc in (whole, settling))
    assert a.outcome == b.outcome == outcome and not b.success
    assert not a.search_stats.settled and b.search_stats.settled
    assert b.search_stats.expansions < a.search_stats.expansions
    assert b.hypotheses and (outcome != Outcome.AMBIGUOUS or len(b.hypotheses) == OPTIONS.hypotheses)
    assert 'the search ended once no place it had not scored could make the answer confident' in b.message


def test_the_search_is_not_settled_before_its_best_leaf_is_known(office_map):
    """settled_check's gates, on leaves given to it: with a node pending above the best
    leaf it never ends the search (the whole search could put that better place first);
    with the same leaves and nothing above them, and a poor fit, it does."""
    matcher = BranchAndBoundMatcher(office_map, SETTLING)
    points = scan_to_points(scan_of(np.random.default_rng(3).uniform(0.5, 3.0, len(ANGLES))))
    pts = matcher.prepare(points.points)
    norm = 255 * len(pts)
    # columns: u, v, heading, optimistic score, evidence score (the map's own say)
    leaves = np.array([[100, 100, 0, int(0.2 * norm), int(0.2 * norm)],
                       [300, 200, 7, int(0.19 * norm), int(0.19 * norm)]], np.int64)
    d0 = 2 * np.pi / matcher.leaf_angles(pts)
    settled = matcher.settled_check(pts, d0, points)
    assert not settled(leaves, int(0.25 * norm))     # a pending node bounds above the best leaf
    assert settled(leaves, int(0.2 * norm))          # none does; nothing unscored can explain enough
    assert BranchAndBoundMatcher(office_map).settled_check(pts, d0, points) is None     # the default: never


def test_a_settled_search_is_never_judged_a_success(office_map):
    """The guard in Matcher.judge: hypotheses judged confident from a search that ended
    early (as if the localizer had dropped a rival) make `search incomplete`, not a success."""
    matcher = BranchAndBoundMatcher(office_map)
    confident = [candidate(0.0, 0.9, 0.0), candidate(5.0, 0.5, 0.0)]
    assert matcher.judge(confident).success
    verdict = matcher.judge(confident, settled='ended early')
    assert verdict.outcome == Outcome.SEARCH_INCOMPLETE and not verdict.success
