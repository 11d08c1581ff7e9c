"""The poor-match floor (verdict.keep_floor with space.poor_fit): while the best leaf is
too poor ever to be confident, the search explores only the band below the lowest fit
that could be confident. It must never change an answer a place could be confident in:
the same scans searched with the band below any best (poor_fit 0) give the same leaves,
hypotheses, covariance and verdict whenever either answer is localized, or both searches
ran to the end with a best that could be confident; and on scans the map cannot explain
it answers `poor match` sooner (where the band below the poor best was not even proved
within the node budget: `search incomplete`)."""
from __future__ import annotations

import dataclasses

import numpy as np
from test_bnb_resume import answer

from global_loc.core.matchers import MatchOptions
from global_loc.core.matchers.bnb import BranchAndBoundMatcher, BranchAndBoundOptions
from global_loc.core.matchers.bnb.verdict import confident_fit
from global_loc.core.outcome import Outcome
from global_loc.core.scan import scan_to_points
from global_loc.sim.changes import changed_world
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import sample_free_poses, simulate_scan


def band_below_any_best(matcher: BranchAndBoundMatcher) -> BranchAndBoundMatcher:
    """The matcher searching the band below its best whatever the best (no poor-match floor)."""
    space_of = matcher.search_space
    matcher.search_space = lambda n_angles, region: space_of(n_angles, region)._replace(poor_fit=0.0)
    return matcher


def cases(office_map, seed: int):
    """(map, scan): the office as mapped (confident answers), heavily changed (low fits),
    and scans of a clutter the map has nowhere (returns at random ranges: the map cannot
    explain them)."""
    rng = np.random.default_rng(seed)
    for truth in sample_free_poses(office_map, 2, rng, clearance=0.5):
        scan = simulate_scan(office_map, truth,
                             LaserConfig(270.0, 541, range_max=20.0, noise_std=0.0, dropout=0.0), rng=rng)
        yield office_map, dataclasses.replace(scan, ranges=rng.uniform(0.5, 8.0, len(scan.ranges)))
    for level in (0, 0, 0, 0, 2, 3):
        truth = sample_free_poses(office_map, 1, rng, clearance=0.5)[0]
        world = changed_world(office_map, level, truth, rng) if level else office_map
        yield office_map, simulate_scan(world, truth,
                                        LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.0), rng=rng)


def test_the_poor_match_floor_never_changes_an_answer_that_could_be_confident(office_map):
    options = BranchAndBoundOptions()
    lowest = confident_fit(options.min_confidence)
    compared = confident = poor = 0
    for m, scan in cases(office_map, 3):
        points = scan_to_points(scan)
        new, old = BranchAndBoundMatcher(m, options), band_below_any_best(BranchAndBoundMatcher(m, options))
        found_new, found_old = new.match(points, MatchOptions()), old.match(points, MatchOptions())
        a_new, a_old = answer(new, found_new), answer(old, found_old)
        best_fit = found_old.stats.best_leaf
        outcomes = {a_new[2][0], a_old[2][0]}
        if Outcome.LOCALIZED in outcomes or (best_fit >= lowest and not found_old.stopped):
            assert a_new == a_old
            compared += 1
            confident += Outcome.LOCALIZED in outcomes
        else:       # a best too poor to be confident: `poor match`, for less work (the band below
            # a poor best may not even be proved within the node budget: `search incomplete`)
            assert a_new[2][0] == Outcome.POOR_MATCH, (a_new[2], a_old[2])
            assert a_old[2][0] in (Outcome.POOR_MATCH, Outcome.SEARCH_INCOMPLETE), a_old[2]
            assert found_new.stats.expansions <= found_old.stats.expansions
            poor += found_new.stats.expansions < found_old.stats.expansions
    assert compared >= 4 and confident >= 1 and poor >= 2, (compared, confident, poor)   # every kind was seen
