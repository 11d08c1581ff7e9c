"""The branch-and-bound matcher: exact against brute force, and right on ray-cast scans."""
import functools
import math

import cv2
import numpy as np
import pytest

from global_loc.localizer import Localizer, pose_error
from global_loc.map_io import from_occupancy_grid
from global_loc.matchers import MatchOptions
from global_loc.matchers.bnb import BranchAndBoundMatcher, BranchAndBoundOptions
from global_loc.raycast import sample_free_poses, simulate_scan
from global_loc.scan import scan_to_points
from global_loc.transform import Rigid2D


def small_room():
    """A 4 x 3 m room at 5 cm with an L-shaped desk and a pillar: no symmetry."""
    grid = np.zeros((60, 80), dtype=int)
    grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = 100
    grid[10:14, 20:45] = 100
    grid[10:30, 41:45] = 100
    grid[40:44, 60:64] = 100
    return from_occupancy_grid(80, 60, 0.05, (0.0, 0.0, 0.0), grid.ravel())


def brute_force_leaves(matcher, pts, d0, n_angles):
    """The score of every leaf (free cell x angle), scored like the search's leaves."""
    rows, cols = np.nonzero(matcher.map.free)
    return np.concatenate([matcher.bounds(0, cols, rows, np.full(len(cols), a), pts, d0) for a in range(n_angles)])


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
    scan = simulate_scan(m, truth, 270.0, 271, 4.0, noise_std=0.01, rng=rng)
    matcher = BranchAndBoundMatcher(m, BranchAndBoundOptions(levels=4))
    matcher.search = functools.partial(matcher.search, slice_expansions=slice_expansions)
    found = matcher.match(scan_to_points(scan), MatchOptions())
    search = matcher.last_search
    assert search['exact'] and search['threads'] == threads
    opencv_threads(1)
    alone = BranchAndBoundMatcher(m, BranchAndBoundOptions(levels=4)).match(scan_to_points(scan), MatchOptions())
    assert [(c.laser_pose.as_tuple(), c.score) for c in found] == [(c.laser_pose.as_tuple(), c.score) for c in alone]
    pts = matcher.prepare(scan_to_points(scan).points)
    scores = brute_force_leaves(matcher, pts, 2 * math.pi / search['angles'], search['angles'])
    assert search['best_leaf'] == pytest.approx(scores.max(), abs=1e-12)
    # every leaf within keep_ratio of the best was found (the hypotheses come from them)
    raw = np.rint(scores * 255 * len(pts))
    assert search['leaves'] == np.count_nonzero(raw >= matcher.options.keep_ratio * raw.max())


def test_bounds_are_never_below_the_leaves_under_them():
    m = small_room()
    rng = np.random.default_rng(5)
    scan = simulate_scan(m, Rigid2D(1.0, 2.0, 0.3), 360.0, 360, 4.0, rng=rng)
    matcher = BranchAndBoundMatcher(m, BranchAndBoundOptions(levels=4))
    pts = matcher.prepare(scan_to_points(scan).points)
    n = 512
    d0 = 2 * math.pi / n
    for level in (1, 2, 3):
        size = 2 ** level
        tu, tv, ta = (rng.integers(0, 80 - size, 40) // size * size, rng.integers(0, 60 - size, 40) // size * size,
                      rng.integers(0, n - size, 40) // size * size)
        bound = matcher.bounds(level, tu, tv, ta, pts, d0)
        for i in range(40):
            du, dv, da = np.meshgrid(np.arange(size), np.arange(size), np.arange(size), indexing='ij')
            leaves = matcher.bounds(0, tu[i] + du.ravel(), tv[i] + dv.ravel(), ta[i] + da.ravel(), pts, d0)
            assert leaves.max() <= bound[i] + 1e-12


@pytest.mark.parametrize('levels', [0, 8])
def test_levels_beyond_what_the_planes_cover_are_a_clear_error(levels):
    with pytest.raises(ValueError, match='bnb levels must be 1 .. 7'):
        BranchAndBoundMatcher(small_room(), BranchAndBoundOptions(levels=levels))


def test_bnb_localizes_raycast_scans_on_the_office(office_map):
    localizer = Localizer(office_map)
    rng = np.random.default_rng(2026)
    errors = []
    for truth in sample_free_poses(office_map, 4, rng):
        scan = simulate_scan(office_map, truth, 270.0, 541, 20.0, noise_std=0.01, dropout=0.02, rng=rng)
        result = localizer.localize(scan, method='bnb')
        errors.append(pose_error(result.pose, truth))
    assert all(d < 0.1 and a < 2.0 for d, a in errors), errors


def symmetric_room():
    """A 6 x 6 m square room with four identical pillars placed four-fold symmetrically."""
    n = 120
    grid = np.zeros((n, n), dtype=int)
    grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = 100
    for r, c in ((30, 30), (30, 86), (86, 30), (86, 86)):
        grid[r:r + 4, c:c + 4] = 100
    return from_occupancy_grid(n, n, 0.05, (0.0, 0.0, 0.0), grid.ravel())


def test_four_fold_symmetric_room_is_ambiguous_with_the_truth_among_the_hypotheses():
    m = symmetric_room()
    truth = Rigid2D(2.0, 1.4, 0.4)
    scan = simulate_scan(m, truth, 360.0, 720, 10.0, noise_std=0.005, rng=np.random.default_rng(3))
    result = Localizer(m).localize(scan, method='bnb')
    assert not result.success
    assert result.message.startswith('ambiguous')
    assert len(result.hypotheses) >= 4
    errors = [pose_error(h.pose, truth) for h in result.hypotheses[:4]]
    assert any(d < 0.1 and a < 2.0 for d, a in errors), errors
    yaws = sorted(math.degrees(h.pose.yaw) % 360 for h in result.hypotheses[:4])
    gaps = np.diff(yaws + [yaws[0] + 360])
    assert np.allclose(gaps, 90, atol=3), yaws     # the four peaks are 90 deg apart


def aisles():
    """A 12 x 6 m store at 5 cm: three identical 8 m shelves make two identical aisles, and
    the whole is symmetric under a half turn about its centre (6, 3)."""
    grid = np.zeros((120, 240), dtype=int)      # OccupancyGrid rows: y = row x 5 cm
    grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = 100
    for y in (1.5, 3.0, 4.5):
        grid[round(y / 0.05) - 3:round(y / 0.05) + 3, 40:200] = 100
    return from_occupancy_grid(240, 120, 0.05, (0.0, 0.0, 0.0), grid.ravel())


def test_identical_aisles_are_ambiguous_with_the_truth_and_its_twins_among_the_hypotheses():
    """At the end of an aisle, looking out (180 deg, 4 m): the other aisle's end and the
    half-turned ends look the same."""
    m = aisles()
    truth = Rigid2D(8.5, 2.25, 0.0)
    twins = [truth, Rigid2D(8.5, 3.75, 0.0), Rigid2D(3.5, 3.75, math.pi), Rigid2D(3.5, 2.25, math.pi)]
    scan = simulate_scan(m, truth, 180.0, 361, 4.0, noise_std=0.005, rng=np.random.default_rng(7))
    result = Localizer(m).localize(scan, method='bnb')
    assert not result.success and result.message.startswith('ambiguous: 3 other place(s)'), result.message
    for twin in twins:
        errors = [pose_error(h.pose, twin) for h in result.hypotheses]
        assert any(d < 0.1 and a < 2.0 for d, a in errors), (twin, errors)


def test_confident_result_has_a_positive_definite_covariance_from_the_landscape(office_map):
    truth = Rigid2D(3.0, 4.0, 0.7)
    scan = simulate_scan(office_map, truth, 270.0, 541, 20.0, noise_std=0.01, rng=np.random.default_rng(4))
    result = Localizer(office_map).localize(scan, method='bnb')
    assert result.success and result.message == 'localized' and result.confidence >= 0.5
    cov = result.covariance
    assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
    assert 1e-5 < cov[0, 0] < 0.05 and 1e-7 < cov[2, 2] < 0.01      # cm-level, not the fixed 0.25 m^2


def test_covariance_of_composition_matches_a_numeric_jacobian():
    from global_loc.transform import covariance_of_composition
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


def twin_rooms(door_b_closed: bool, chair_in: str):
    """Two identical 4 x 3.5 m rooms (A left, B right) off one long featureless corridor,
    each with a door onto it; B's door may be closed, and a 0.3 m chair may stand in one."""
    res = 0.05
    w, h = int(24 / res), int(5.5 / res)
    grid = np.zeros((h, w), dtype=int)

    def occ(x0, x1, y0, y1, value=100):      # a box in metres (y up)
        rows = slice(h - int(round(y1 / res)), h - int(round(y0 / res)))
        grid[rows, int(round(x0 / res)):int(round(x1 / res))] = value

    occ(0, 24, 0, 0.05), occ(0, 24, 5.45, 5.5), occ(0, 0.05, 0, 5.5), occ(23.95, 24, 0, 5.5)
    occ(0, 24, 2.0, 2.05)                                   # the rooms' wall onto the corridor
    for x in (2, 6, 16, 20):
        occ(x, x + 0.05, 2.0, 5.5)
    occ(3.6, 4.4, 2.0, 2.05, 0)                            # A's door
    if not door_b_closed:
        occ(17.6, 18.4, 2.0, 2.05, 0)                      # B's door
    cx = {'A': 5.0, 'B': 19.0}[chair_in]
    occ(cx, cx + 0.3, 4.2, 4.5)
    return from_occupancy_grid(w, h, res, (0.0, 0.0, 0.0), grid[::-1].ravel())


def test_a_match_whose_beams_pass_through_walls_is_ranked_below_one_that_does_not():
    """The robot stands in room A, looking out through A's open door; A's chair is mapped
    in B, so the scan's end points fit B better, but B's door is closed: a third of the
    beams would pass through it. A comes first; the result stays ambiguous (on the end
    points alone B is as good), with B among the hypotheses."""
    world = twin_rooms(door_b_closed=False, chair_in='A')
    mapped = twin_rooms(door_b_closed=True, chair_in='B')
    truth = Rigid2D(4.0, 3.4, -math.pi / 2 + 0.2)
    scan = simulate_scan(world, truth, 270.0, 541, 6.0, noise_std=0.005, rng=np.random.default_rng(7))
    matcher = BranchAndBoundMatcher(mapped)
    candidates = matcher.match(scan_to_points(scan), MatchOptions())
    twin_in_b = Rigid2D(truth.x + 14.0, truth.y, truth.yaw)
    in_b = [c for c in candidates if pose_error(c.laser_pose, twin_in_b)[0] < 0.1]
    assert in_b, 'B should be a hypothesis'
    assert in_b[0].explained > candidates[0].explained           # the end points alone prefer B ...
    assert in_b[0].see_through > candidates[0].see_through + 0.1  # ... but its beams cross B's door
    d, a = pose_error(candidates[0].laser_pose, truth)
    assert d < 0.1 and a < 2.0
    result = Localizer(mapped).localize(scan, method='bnb')
    assert not result.success and result.message.startswith('ambiguous'), result.message
    assert pose_error(result.pose, truth)[0] < 0.1


@pytest.mark.parametrize('threads', [2, 3])
def test_equal_scores_give_the_same_hypotheses_whatever_the_threads(threads, opencv_threads):
    """A 60 deg look at one wall of a long featureless corridor: thousands of poses score
    exactly alike, and which of them a peak is reported at must not depend on which
    thread found it first."""
    grid = np.zeros((40, 240), dtype=int)
    grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = 100
    m = from_occupancy_grid(240, 40, 0.05, (0.0, 0.0, 0.0), grid.ravel())
    scan = simulate_scan(m, Rigid2D(6.0, 1.0, math.pi / 2), 60.0, 61, 4.0, noise_std=0.0,
                         rng=np.random.default_rng(3))
    points = scan_to_points(scan)
    results = []
    for n, slice_expansions in ((1, 20000), (threads, 5)):
        opencv_threads(n)
        matcher = BranchAndBoundMatcher(m, BranchAndBoundOptions(levels=4))
        matcher.search = functools.partial(matcher.search, slice_expansions=slice_expansions)
        results.append([(c.laser_pose.as_tuple(), c.score) for c in matcher.match(points, MatchOptions())])
    assert len(results[0]) >= 4 and results[0] == results[1]
