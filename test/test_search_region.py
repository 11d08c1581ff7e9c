"""Search priors: the region's own rule, and every matcher answering only inside it; bnb
expanding fewer nodes the smaller the region (its search is cut in the kernel)."""
import math

import numpy as np
import pytest

from conftest import aisles, assert_pose_near
from global_loc.core.localizer import Localizer
from global_loc.core.matchers import MatchOptions
from global_loc.core.outcome import Outcome
from global_loc.core.scan import scan_to_points
from global_loc.core.search_region import SearchRegion
from global_loc.core.transform import Rigid2D
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import sample_free_poses, simulate_scan

AISLE_END = Rigid2D(8.5, 2.25, 0.0)


@pytest.fixture(scope='module')
def aisle_scan():
    """At an aisle's end looking out: the other aisle's end and both half-turned ends look the same."""
    m = aisles()
    return m, simulate_scan(m, AISLE_END,
                            LaserConfig(180.0, 361, range_max=4.0, noise_std=0.005, dropout=0.0),
                            rng=np.random.default_rng(7))


def test_region_contains_by_distance_and_heading():
    region = SearchRegion(Rigid2D(1.0, 1.0, math.pi), 2.0, math.radians(30))
    assert region.contains(Rigid2D(2.0, 2.0, -math.pi + 0.1))            # across the +-pi seam
    assert not region.contains(Rigid2D(3.5, 1.0, math.pi))               # too far
    assert not region.contains(Rigid2D(1.0, 1.0, math.pi / 2))           # facing away
    assert SearchRegion(Rigid2D(0, 0, 0)).contains(Rigid2D(100.0, -50.0, 2.0))   # no bound: anywhere
    assert not SearchRegion(Rigid2D(0, 0, 0)).bounded
    laser = SearchRegion(Rigid2D(1.0, 1.0, 0.5), 2.0, 0.2).for_laser(Rigid2D(0.3, 0.4, 0.1))
    assert (laser.radius_m, laser.center.yaw, laser.yaw_tolerance) == pytest.approx((2.5, 0.6, 0.2))


@pytest.mark.parametrize('values', [(float('nan'), 1.0, 0.0), (0.0, -1.0, 0.0), (0.0, 1.0, -0.1),
                                    (0.0, float('inf'), 0.0)])
def test_bad_region_is_a_clear_error(values):
    x, radius, tolerance = values
    with pytest.raises(ValueError, match='search r|must be'):
        SearchRegion(Rigid2D(x, 0.0, 0.0), radius, tolerance)


def test_a_prior_settles_the_twin_aisles_and_the_search_shrinks(aisle_scan):
    m, scan = aisle_scan
    localizer = Localizer(m)
    alone = localizer.localize(scan)
    assert alone.outcome == Outcome.AMBIGUOUS
    near = SearchRegion(Rigid2D(8.0, 2.0, 0.0), 1.0)
    result = localizer.localize(scan, region=near)
    assert result.outcome == Outcome.LOCALIZED
    assert_pose_near(result.pose, AISLE_END, 0.1, 2.0)
    # heading alone excludes the half-turned twins, not the other aisle
    facing = localizer.localize(scan, region=SearchRegion(Rigid2D(0.0, 0.0, 0.2), 0.0, math.radians(30)))
    assert facing.outcome == Outcome.AMBIGUOUS and facing.message.startswith('ambiguous: 1 other place')
    assert all(abs(h.pose.yaw) < math.radians(30) + 0.2 for h in facing.hypotheses)
    # fewer expansions with the region (a count, not a time: the machine is noisy)
    matcher = localizer.matcher('bnb')
    points = scan_to_points(scan)
    whole = matcher.match(points, MatchOptions()).stats
    small = matcher.match(points, MatchOptions(region=near)).stats
    assert small.exact and small.top_nodes < whole.top_nodes / 2 and small.expansions < whole.expansions / 3


@pytest.mark.parametrize('method', ['template_ccoeff', 'features_orb'])
def test_thesis_matchers_answer_only_inside_the_region(office_map, method):
    truth = Rigid2D(3.0, 4.0, 0.7)
    scan = simulate_scan(office_map, truth,
                         LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.0),
                         rng=np.random.default_rng(7))
    region = SearchRegion(Rigid2D(12.0, 8.0, 0.0), 2.0, math.radians(45))   # elsewhere: the truth is outside
    result = Localizer(office_map).localize(scan, method=method, region=region)
    assert all(region.contains(h.pose) for h in result.hypotheses)
    assert not result.success or region.contains(result.pose)
    if method == 'template_ccoeff':
        right = Localizer(office_map).localize(scan, method=method,
                                               region=SearchRegion(Rigid2D(3.5, 4.5, 0.5), 2.0, math.radians(20)))
        assert right.success
        assert_pose_near(right.pose, truth)


def test_the_nearest_pose_of_a_region_and_a_wider_region():
    region = SearchRegion(Rigid2D(1.0, 1.0, math.pi), 2.0, math.radians(10))
    inside = Rigid2D(2.0, 1.5, math.pi - 0.1)
    assert region.nearest(inside) == inside
    moved = region.nearest(Rigid2D(5.0, 1.0, -math.pi + 0.5))        # 4 m out, 29 deg past the window (across +-pi)
    assert moved.as_tuple() == pytest.approx((3.0, 1.0, -math.pi + math.radians(10)))
    assert region.contains(moved)
    wider = region.widened_by(0.5, math.radians(5))
    assert wider.radius_m == 2.5 and wider.yaw_tolerance == pytest.approx(math.radians(15))
    unbounded = SearchRegion(Rigid2D(), 0.0, 0.0).widened_by(1.0, 1.0)
    assert not unbounded.bounded


def test_a_heading_prior_tighter_than_the_search_localizes_as_often_as_a_loose_one(office_map):
    """A prior is a constraint: the refinement moves the first of these scans' best 0.47 deg
    from the truth, out of a 0.01 deg window, and that window once lost the very place it
    names (no_match). Now each answer lies inside the prior, as often a success as 0.5 deg's."""
    localizer = Localizer(office_map)
    rng = np.random.default_rng(0)
    for truth in list(sample_free_poses(office_map, 8, rng))[:4]:
        scan = simulate_scan(office_map, truth,
                             LaserConfig(270, 541, range_max=20.0, noise_std=0.01, dropout=0.02), rng=rng)
        loose = localizer.localize(scan, region=SearchRegion(truth, 0.0, math.radians(0.5)))
        for tolerance in (0.01, 0.1):
            prior = SearchRegion(truth, 0.0, math.radians(tolerance))
            tight = localizer.localize(scan, region=prior)
            assert tight.success >= loose.success, (tolerance, truth, tight.message, loose.message)
            assert all(prior.contains(h.pose) for h in tight.hypotheses)
            if tight.success:
                assert_pose_near(tight.pose, truth, 0.1, 0.5)
