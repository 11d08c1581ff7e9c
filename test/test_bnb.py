"""The branch-and-bound matcher: exact against brute force, and right on ray-cast scans."""
import math

import cv2
import numpy as np
import pytest

from conftest import (
    aisles,
    any_pose_near,
    assert_pose_near,
    brute_force_leaves,
    grid_map,
    small_room,
    symmetric_room,
    twin_rooms,
    walled,
)
from global_loc.core.localizer import Localizer, LocalizerConfig
from global_loc.core.map_io import make_map
from global_loc.core.matchers import MatchOptions
from global_loc.core.matchers.bnb import BranchAndBoundMatcher, BranchAndBoundOptions, grids
from global_loc.core.matchers.bnb.grids import PrecomputationGridStack
from global_loc.core.matchers.bnb.verdict import searched_keep
from global_loc.core.outcome import Outcome
from global_loc.core.scan import scan_to_points
from global_loc.core.transform import Rigid2D, pose_error
from global_loc.sim.changes import changed_world
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import sample_free_poses, simulate_scan


@pytest.fixture
def opencv_threads():
    """Sets cv2.setNumThreads (which the search's thread count follows) for one test."""
    before = cv2.getNumThreads()
    yield cv2.setNumThreads
    cv2.setNumThreads(before)


@pytest.mark.parametrize('seed, threads, slice_expansions', [(1, 1, 20000), (2, 1, 20000), (3, 1, 20000),
                                                             (1, 2, 20000), (2, 3, 7), (3, 2, 5)])
def test_branch_and_bound_finds_the_brute_force_maximum_and_every_pose_near_it(seed, threads, slice_expansions,
                                                                                opencv_threads):
    """One thread or several (short slices: threads run out of nodes and take half of
    another's heap, many times), the same exact result."""
    opencv_threads(threads)
    m = small_room()
    rng = np.random.default_rng(seed)
    truth = sample_free_poses(m, 1, rng, clearance=0.3)[0]
    scan = simulate_scan(m, truth, LaserConfig(270.0, 271, range_max=4.0, noise_std=0.01, dropout=0.0), rng=rng)
    # the narrow band (band_allowance 0.03: the default's whole keep_ratio band is the same search, wider)
    options = BranchAndBoundOptions(levels=4, band_allowance=0.03)
    matcher = BranchAndBoundMatcher(m, options, slice_expansions=slice_expansions)
    found = matcher.match(scan_to_points(scan), MatchOptions())
    search = found.stats
    assert search.exact and search.threads == threads
    opencv_threads(1)
    alone = BranchAndBoundMatcher(m, options).match(scan_to_points(scan), MatchOptions())
    assert [(c.laser_pose.as_tuple(), c.score) for c in found.candidates] == \
        [(c.laser_pose.as_tuple(), c.score) for c in alone.candidates]
    pts = matcher.prepare(scan_to_points(scan).points)
    scores = brute_force_leaves(matcher, pts, 2 * math.pi / search.angles, search.angles)
    assert search.best_leaf == pytest.approx(scores.max(), abs=1e-12)
    # every leaf within the band searched at the best's fit was found (the hypotheses come from them):
    # the narrow band, or keep_ratio's whole band where the search resumed with it (test_bnb_resume)
    raw = np.rint(scores * 255 * len(pts))
    opt = matcher.options
    keep = searched_keep(raw.max() / (255 * len(pts)), opt.keep_ratio, opt.min_confidence, search.band_allowance)
    assert keep > opt.keep_ratio or search.band_allowance == 1.0
    assert search.leaves == np.count_nonzero(raw >= math.ceil(keep * raw.max()))
    whole = BranchAndBoundMatcher(m, BranchAndBoundOptions(levels=4)).match(scan_to_points(scan), MatchOptions())
    assert whole.stats.leaves == np.count_nonzero(raw >= math.ceil(opt.keep_ratio * raw.max()))


@pytest.mark.parametrize('plane_memory_mb', [320.0, 1e-3])     # the default; planes coarser from level 1 on
def test_bounds_are_never_below_the_leaves_under_them(plane_memory_mb):
    m = small_room()
    rng = np.random.default_rng(5)
    scan = simulate_scan(m, Rigid2D(1.0, 2.0, 0.3),
                         LaserConfig(360.0, 360, range_max=4.0, noise_std=0.0, dropout=0.0), rng=rng)
    matcher = BranchAndBoundMatcher(m, BranchAndBoundOptions(levels=5, plane_memory_mb=plane_memory_mb))
    pts = matcher.prepare(scan_to_points(scan).points)
    n = 512     # a point at the scan's largest range moves just under a cell per angle step
    d0 = 2 * math.pi / n
    for level in (1, 2, 3, 4):
        size = 2 ** level
        tu, tv, ta = (rng.integers(0, 80 - size, 40) // size * size, rng.integers(0, 60 - size, 40) // size * size,
                      rng.integers(0, n - size, 40) // size * size)
        bound = matcher.bounds(level, tu, tv, ta, pts, d0)
        for i in range(40):
            du, dv, da = np.meshgrid(np.arange(size), np.arange(size), np.arange(size), indexing='ij')
            leaves = matcher.bounds(0, tu[i] + du.ravel(), tv[i] + dv.ravel(), ta[i] + da.ravel(), pts, d0)
            assert leaves.max() <= bound[i] + 1e-12


def test_planes_over_their_memory_budget_are_stored_coarser_and_the_search_finds_the_same():
    """A map whose planes would exceed bnb.plane_memory_mb stores its coarse levels at
    lower resolution, from lower levels on, until they fit (not below level 1: the
    leaves read the map's own resolution): looser bounds, so more nodes, but the same
    leaves, hypotheses and scores."""
    m = small_room()
    rng = np.random.default_rng(7)
    scan = simulate_scan(m, sample_free_poses(m, 1, rng, clearance=0.3)[0],
                         LaserConfig(270.0, 271, range_max=4.0, noise_std=0.01, dropout=0.0), rng=rng)
    default = BranchAndBoundMatcher(m, BranchAndBoundOptions(levels=5))
    budget = (default.stack.planes.flat.nbytes + 1) / 1e6      # (+1 byte: MB rounding)
    results = {}
    for mb, shift_from in ((budget, 3), (budget * 0.9, 2), (1e-3, 1)):
        matcher = BranchAndBoundMatcher(m, BranchAndBoundOptions(levels=5, plane_memory_mb=mb))
        assert matcher.stack.shift_from == shift_from
        assert matcher.stack.planes.flat.nbytes <= mb * 1e6 or shift_from == 1    # 1: as coarse as it gets
        found = matcher.match(scan_to_points(scan), MatchOptions())
        results[shift_from] = ([(c.laser_pose.as_tuple(), c.score) for c in found.candidates], found.stats.leaves,
                               found.stats.expansions)
    assert results[1][:2] == results[2][:2] == results[3][:2] and results[3][0]
    assert results[1][2] >= results[3][2]      # looser bounds: at least as many nodes


def test_planes_built_a_few_rows_at_a_time_are_those_built_at_once(monkeypatch):
    """The shifted planes are dilated ROWS_PER_PASS rows at a time (a big map's memory):
    with passes of 16 rows, on an odd-sized map taller than the 256-row conversion pass
    and planes coarser from level 1 on (every shift), the same planes as in one pass."""
    rng = np.random.default_rng(11)
    occupancy = np.where(rng.random((301, 157)) < 0.03, 100, 0).astype(np.int8)
    occupancy[rng.random(occupancy.shape) < 0.05] = -1
    m = make_map(occupancy, 0.05, Rigid2D())
    options = BranchAndBoundOptions(plane_memory_mb=1e-3)
    at_once = PrecomputationGridStack(m, options)
    monkeypatch.setattr(grids, 'ROWS_PER_PASS', 16)
    by_rows = PrecomputationGridStack(m, options)
    assert at_once.shift_from == 1 and np.array_equal(at_once.planes.flat, by_rows.planes.flat)
    assert np.array_equal(at_once.field, by_rows.field) and np.array_equal(at_once.free.flags, by_rows.free.flags)


@pytest.mark.parametrize('levels', [0, 8])
def test_levels_beyond_what_the_planes_cover_are_a_clear_error(levels):
    with pytest.raises(ValueError, match=r'bnb.levels must be in \[1, 7\]'):
        BranchAndBoundMatcher(small_room(), BranchAndBoundOptions(levels=levels))


def test_bnb_localizes_raycast_scans_on_the_office(office_map):
    localizer = Localizer(office_map)
    rng = np.random.default_rng(2026)
    for truth in sample_free_poses(office_map, 4, rng):
        scan = simulate_scan(office_map, truth,
                             LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.02), rng=rng)
        result = localizer.localize(scan, method='bnb')
        assert_pose_near(result.pose, truth, 0.1, 2.0)
        # the search's statistics reach the result; its time is part of the localization's
        assert result.search_stats.exact and result.search_stats.expansions > 0
        assert 0 < result.search_stats.search_s < result.time_s


def test_four_fold_symmetric_room_is_ambiguous_with_the_truth_among_the_hypotheses():
    m = symmetric_room()
    truth = Rigid2D(2.0, 1.4, 0.4)
    scan = simulate_scan(m, truth,
                         LaserConfig(360.0, 720, range_max=10.0, noise_std=0.005, dropout=0.0),
                         rng=np.random.default_rng(3))
    result = Localizer(m).localize(scan, method='bnb')
    assert not result.success
    assert result.outcome == Outcome.AMBIGUOUS and result.message.startswith('ambiguous')
    assert len(result.hypotheses) >= 4
    assert any_pose_near([h.pose for h in result.hypotheses[:4]], truth, 0.1, 2.0)
    yaws = sorted(math.degrees(h.pose.yaw) % 360 for h in result.hypotheses[:4])
    gaps = np.diff(yaws + [yaws[0] + 360])
    assert np.allclose(gaps, 90, atol=3), yaws     # the four peaks are 90 deg apart


def test_identical_aisles_are_ambiguous_with_the_truth_and_its_twins_among_the_hypotheses():
    """At the end of an aisle, looking out (180 deg, 4 m): the other aisle's end and the
    half-turned ends look the same."""
    m = aisles()
    truth = Rigid2D(8.5, 2.25, 0.0)
    twins = [truth, Rigid2D(8.5, 3.75, 0.0), Rigid2D(3.5, 3.75, math.pi), Rigid2D(3.5, 2.25, math.pi)]
    scan = simulate_scan(m, truth,
                         LaserConfig(180.0, 361, range_max=4.0, noise_std=0.005, dropout=0.0),
                         rng=np.random.default_rng(7))
    result = Localizer(m).localize(scan, method='bnb')
    assert result.outcome == Outcome.AMBIGUOUS
    assert not result.success and result.message.startswith('ambiguous: 3 other place(s)'), result.message
    for twin in twins:
        assert any_pose_near([h.pose for h in result.hypotheses], twin, 0.1, 2.0), (twin, result.hypotheses)


def test_confident_result_has_a_positive_definite_covariance_from_the_landscape(office_map):
    truth = Rigid2D(3.0, 4.0, 0.7)
    scan = simulate_scan(office_map, truth,
                         LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.0),
                         rng=np.random.default_rng(4))
    result = Localizer(office_map).localize(scan, method='bnb')
    assert result.outcome == Outcome.LOCALIZED and result.message.startswith('localized') and result.confidence >= 0.5
    cov = result.covariance
    assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
    assert 1e-5 < cov[0, 0] < 0.05 and 1e-7 < cov[2, 2] < 0.01      # cm-level, not the fixed 0.25 m^2


def test_covariance_of_composition_matches_a_numeric_jacobian():
    from global_loc.core.transform import covariance_of_composition
    pose, child = Rigid2D(1.0, 2.0, 0.8), Rigid2D(0.16, -0.05, 0.0)
    cov = np.diag([0.01, 0.02, 0.003])
    eps = 1e-6
    jac = np.zeros((3, 3))
    for i in range(3):
        d = np.zeros(3)
        d[i] = eps
        plus = Rigid2D(*(np.array(pose.as_tuple()) + d)) * child
        minus = Rigid2D(*(np.array(pose.as_tuple()) - d)) * child
        jac[:, i] = (np.array(plus.as_tuple()) - np.array(minus.as_tuple())) / (2 * eps)
    assert covariance_of_composition(pose, cov, child) == pytest.approx(jac @ cov @ jac.T, abs=1e-9)


def test_a_match_whose_beams_pass_through_walls_is_ranked_below_one_that_does_not():
    """The robot stands in room A, looking out through A's open door; A's chair is mapped
    in B, so the scan's end points fit B better, but B's door is closed: a third of the
    beams would pass through it. A comes first; the result stays ambiguous (on the end
    points alone B is as good), with B among the hypotheses."""
    world = twin_rooms(door_b_closed=False, chair_in='A')
    mapped = twin_rooms(door_b_closed=True, chair_in='B')
    truth = Rigid2D(4.0, 3.4, -math.pi / 2 + 0.2)
    scan = simulate_scan(world, truth,
                         LaserConfig(270.0, 541, range_max=6.0, noise_std=0.005, dropout=0.0),
                         rng=np.random.default_rng(7))
    matcher = BranchAndBoundMatcher(mapped)
    candidates = matcher.match(scan_to_points(scan), MatchOptions()).candidates
    twin_in_b = Rigid2D(truth.x + 14.0, truth.y, truth.yaw)
    in_b = [c for c in candidates if pose_error(c.laser_pose, twin_in_b)[0] < 0.1]
    assert in_b, 'B should be a hypothesis'
    assert in_b[0].explained > candidates[0].explained           # the end points alone prefer B ...
    assert in_b[0].see_through > candidates[0].see_through + 0.1  # ... but its beams cross B's door
    assert_pose_near(candidates[0].laser_pose, truth, 0.1, 2.0)
    result = Localizer(mapped).localize(scan, method='bnb')
    assert not result.success and result.message.startswith('ambiguous'), result.message
    assert pose_error(result.pose, truth)[0] < 0.1


@pytest.mark.parametrize('threads', [2, 3])
def test_equal_scores_give_the_same_hypotheses_whatever_the_threads(threads, opencv_threads):
    """A 60 deg look at one wall of a long featureless corridor: thousands of poses score
    exactly alike, and which of them a peak is reported at must not depend on which
    thread found it first."""
    m = grid_map(walled(40, 240))
    scan = simulate_scan(m, Rigid2D(6.0, 1.0, math.pi / 2),
                         LaserConfig(60.0, 61, range_max=4.0, noise_std=0.0, dropout=0.0), rng=np.random.default_rng(3))
    points = scan_to_points(scan)
    results = []
    for n, slice_expansions in ((1, 20000), (threads, 5)):
        opencv_threads(n)
        matcher = BranchAndBoundMatcher(m, BranchAndBoundOptions(levels=4), slice_expansions=slice_expansions)
        results.append([(c.laser_pose.as_tuple(), c.score) for c in matcher.match(points, MatchOptions()).candidates])
    assert len(results[0]) >= 4 and results[0] == results[1]


@pytest.mark.parametrize('limit', [{'bnb': BranchAndBoundOptions(max_nodes=5)}, {'max_search_s': 0.0}])
def test_a_search_stopped_before_any_leaf_still_returns_its_best_leaf_as_a_hypothesis(office_map, limit):
    """A scan of a changed world (boxes, people, open doors not in the map) and a search
    stopped by its node budget (5 expansions: too few to reach a leaf best-first) or at
    once by its time limit: the greedy dive's leaf is there from the start, so the result
    is `search incomplete` with the best of what was explored - never an empty list."""
    rng = np.random.default_rng(5)
    truth = sample_free_poses(office_map, 1, rng, clearance=0.5)[0]
    scan = simulate_scan(changed_world(office_map, 3, truth, rng), truth,
                         LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.0), rng=rng)
    result = Localizer(office_map, LocalizerConfig(**limit)).localize(scan, method='bnb')
    assert result.outcome == Outcome.SEARCH_INCOMPLETE and not result.success
    assert 'best of what was explored, see the hypotheses' in result.message
    assert result.hypotheses and result.pose is not None and result.search_stats.expansions <= 6


def test_the_covariance_of_a_real_log_like_scan_covers_its_error(office_map):
    """Scans with 2 cm noise against a map whose right half was drawn a cell off (a map
    built from another run): the truth lies inside the published 2 sigma ellipsoid (chi-square,
    3 degrees of freedom) on at least 80% of the confident answers and inside 1 sigma on at
    least half - the covariance grows with the residuals at the answer (refine.residual_spread),
    where a landscape of independent points alone held it to the map's cells (~1.4 cm)."""
    from global_loc.core.map_io import make_map
    from global_loc.sim.raycast import sample_free_poses
    grid = office_map.occupancy.copy()
    half = grid.shape[1] // 2
    grid[:, half:] = np.roll(np.roll(grid[:, half:], 1, axis=1), 1, axis=0)
    shifted = Localizer(make_map(grid, office_map.resolution, office_map.origin, 'office, right half a cell off'))
    rng = np.random.default_rng(7)
    d2 = []
    for pose in sample_free_poses(office_map, 12, rng, clearance=0.5):
        result = shifted.localize(simulate_scan(office_map, pose,
                                                LaserConfig(270, 541, range_max=20.0, noise_std=0.02, dropout=0.02),
                                                rng=rng))
        if result.success:
            e = np.array([result.pose.x - pose.x, result.pose.y - pose.y,
                          math.remainder(result.pose.yaw - pose.yaw, 2 * math.pi)])
            d2.append(float(e @ np.linalg.solve(result.covariance, e)))
    assert len(d2) >= 8, d2
    assert np.mean(np.array(d2) <= 8.02) >= 0.8 and np.mean(np.array(d2) <= 3.53) >= 0.5, d2
