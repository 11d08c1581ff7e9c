"""A narrow band's search resumes with the lower floor of keep_ratio's whole band
(search.Resume): it then ends exactly as a search with the whole band from the start -
the same leaves, hypotheses, covariance and verdict - and, not resumed, it is the narrow
band's search exactly."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from conftest import brute_force_leaves, small_room
from global_loc.core.matchers import MatchOptions
from global_loc.core.matchers.bnb import BranchAndBoundMatcher, BranchAndBoundOptions
from global_loc.core.matchers.bnb.search import Resume
from global_loc.core.matchers.bnb.verdict import searched_keep
from global_loc.core.outcome import Outcome
from global_loc.core.scan import scan_to_points
from global_loc.core.transform import Rigid2D
from global_loc.sim.changes import changed_world
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import sample_free_poses, simulate_scan

NARROW = dict(band_allowance=0.03)


@pytest.fixture
def opencv_threads():
    before = cv2.getNumThreads()
    yield cv2.setNumThreads
    cv2.setNumThreads(before)


def forced(matcher: BranchAndBoundMatcher, resume: bool) -> BranchAndBoundMatcher:
    """The matcher with its resume rule replaced by one that always (or never) resumes."""
    rule = matcher.resume_rule

    def always(space, pts, d0, points):
        return Resume(rule(space, pts, d0, points).space, lambda leaves: resume)
    matcher.resume_rule = always
    return matcher


def answer(matcher: BranchAndBoundMatcher, found) -> tuple:
    """Everything a localization reports of a match: hypotheses, covariance and verdict."""
    verdict = matcher.judge(found.candidates, found.stopped, found.settled, found.stats)
    hypotheses = [(c.laser_pose.as_tuple(), c.score, c.explained, c.see_through) for c in found.candidates]
    covariance = found.candidates[0].covariance.tolist() if found.candidates else None
    return hypotheses, covariance, (verdict.outcome, verdict.confidence, verdict.message), found.stats.leaves, \
        found.stats.best_leaf


def scans(seed: int, count: int):
    """(map, points): ray-cast scans of a small room, and of the office as mapped and changed."""
    rng = np.random.default_rng(seed)
    room = small_room()
    for truth in sample_free_poses(room, count, rng, clearance=0.3):
        laser = LaserConfig(270.0, 271, range_max=4.0, noise_std=0.01, dropout=0.0)
        yield room, dict(levels=4), scan_to_points(simulate_scan(room, truth, laser, rng=rng))


@pytest.mark.parametrize('threads, slice_expansions', [(1, 20000), (2, 20000), (2, 7)])
def test_a_resumed_search_ends_exactly_as_one_with_the_lower_floor_from_the_start(threads, slice_expansions,
                                                                                  opencv_threads, office_map):
    opencv_threads(threads)
    rng = np.random.default_rng(11)
    cases = list(scans(5, 3))
    for level in (0, 3):       # the office as mapped, and heavily changed (low fits, rivals)
        truth = sample_free_poses(office_map, 1, rng, clearance=0.5)[0]
        world = changed_world(office_map, level, truth, rng) if level else office_map
        laser = LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.0)
        cases.append((office_map, {}, scan_to_points(simulate_scan(world, truth, laser, rng=rng))))
    for m, extra, points in cases:
        resumed = forced(BranchAndBoundMatcher(m, BranchAndBoundOptions(**extra, **NARROW), slice_expansions),
                         True)
        whole = BranchAndBoundMatcher(m, BranchAndBoundOptions(**extra))
        found = resumed.match(points, MatchOptions())
        assert found.stats.exact and found.stats.band_allowance == 1.0
        assert answer(resumed, found) == answer(whole, whole.match(points, MatchOptions()))


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_a_search_not_resumed_keeps_exactly_the_narrow_bands_leaves(seed):
    m, extra, points = next(scans(seed, 1))
    matcher = forced(BranchAndBoundMatcher(m, BranchAndBoundOptions(**extra, **NARROW)), False)
    search = matcher.match(points, MatchOptions()).stats
    assert search.exact and search.band_allowance == 0.03
    pts = matcher.prepare(points.points)
    raw = np.rint(brute_force_leaves(matcher, pts, 2 * math.pi / search.angles, search.angles) * 255 * len(pts))
    opt = matcher.options
    keep = searched_keep(raw.max() / (255 * len(pts)), opt.keep_ratio, opt.min_confidence, opt.band_allowance)
    assert keep > opt.keep_ratio          # a good fit: the band is narrower than keep_ratio's
    assert search.leaves == np.count_nonzero(raw >= math.ceil(keep * raw.max()))


def test_the_rule_resumes_a_confident_answer_whose_rivals_the_band_may_have_cut(office_map):
    """At band_allowance 0.03 a place below the band (8% behind a full fit), refined up to
    REFINED_GAIN higher, could come within the 5% lead: the rule resumes, and the answer
    is the whole band's."""
    truth = Rigid2D(12.0, 8.0, -2.0)
    points = scan_to_points(simulate_scan(office_map, truth,
                                          LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.0),
                                          rng=np.random.default_rng(4)))
    narrow = BranchAndBoundMatcher(office_map, BranchAndBoundOptions(**NARROW))
    whole = BranchAndBoundMatcher(office_map)
    found = narrow.match(points, MatchOptions())
    assert found.stats.band_allowance == 1.0
    assert answer(narrow, found) == answer(whole, whole.match(points, MatchOptions()))
    assert answer(narrow, found)[2][0] == Outcome.LOCALIZED
