"""The poor-match floor (verdict.keep_floor with space.poor_fit): while the best leaf is
too poor ever to be confident, the search expands only nodes that could hold a leaf at the
lowest fit that could be confident, holding the band below it for the rivals of such a
leaf. It must never change an answer a place could be confident in: the same scans
searched with the band below any best (poor_fit 0), or with the band below the lowest
confident fit expanded (poor_band 1), give the same leaves, hypotheses, covariance and
verdict whenever either answer is localized, or both searches ran to the end with a best
that could be confident; and on scans the map cannot explain it answers `poor match`
sooner (where the band below the poor best was not even proved within the node budget:
`search incomplete`)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_bnb_resume import answer

from global_loc.core.matchers import MatchOptions
from global_loc.core.matchers.bnb import BranchAndBoundMatcher, BranchAndBoundOptions
from global_loc.core.matchers.bnb.verdict import confident_fit
from global_loc.core.outcome import Outcome
from global_loc.core.scan import scan_to_points
from global_loc.sim.changes import changed_world
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import sample_free_poses, simulate_scan


def searching(matcher: BranchAndBoundMatcher, **space) -> BranchAndBoundMatcher:
    """The matcher with its search space's fields replaced: poor_fit=0.0, the band below its
    best whatever the best (no poor-match floor); poor_band=1.0, the band below the lowest
    confident fit expanded while the best is under it."""
    space_of = matcher.search_space
    matcher.search_space = lambda n_angles, region: space_of(n_angles, region)._replace(**space)
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


@pytest.mark.parametrize('old_space', [{'poor_fit': 0.0}, {'poor_band': 1.0}])
def test_the_poor_match_floor_never_changes_an_answer_that_could_be_confident(office_map, old_space):
    options = BranchAndBoundOptions()
    lowest = confident_fit(options.min_confidence)
    compared = confident = poor = 0
    for m, scan in cases(office_map, 3):
        points = scan_to_points(scan)
        new, old = BranchAndBoundMatcher(m, options), searching(BranchAndBoundMatcher(m, options), **old_space)
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


def test_a_best_just_above_the_confident_fit_is_searched_as_with_the_band_expanded(office_map):
    """Office scans with 60% of their ranges at random (best leaves of 0.40 - 0.42, just above
    the confident fit, whose band reaches below it): the search that held the band below the
    confident fit while its best was under it expands what the search that expanded it
    does, and answers alike - held nodes are not dropped."""
    options = BranchAndBoundOptions()
    lowest = confident_fit(options.min_confidence)
    rng = np.random.default_rng(0)
    checked = 0
    truths = [sample_free_poses(office_map, 1, rng, clearance=0.5)[0] for _ in range(4)]
    for truth in truths[1:]:        # (the first one's scan fits better: its band stays above the confident fit)
        scan = simulate_scan(office_map, truth, LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.0),
                             rng=rng)
        ranges = scan.ranges.copy()
        scrambled = rng.random(len(ranges)) < 0.6
        ranges[scrambled] = rng.uniform(0.5, 8.0, int(scrambled.sum()))
        points = scan_to_points(dataclasses.replace(scan, ranges=ranges))
        held = BranchAndBoundMatcher(office_map, options)
        expanded = searching(BranchAndBoundMatcher(office_map, options), poor_band=1.0)
        found_held, found_expanded = held.match(points, MatchOptions()), expanded.match(points, MatchOptions())
        assert lowest <= found_expanded.stats.best_leaf < lowest / 0.9, found_expanded.stats.best_leaf
        assert answer(held, found_held) == answer(expanded, found_expanded)
        assert found_held.stats.expansions >= 0.99 * found_expanded.stats.expansions
        checked += 1
    assert checked == 3
