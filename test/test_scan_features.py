"""`features` (core/matchers/scan_features.py): laser keypoints of the scan matched to those of
views of the map find simulated poses that the thesis's image features (features_orb) miss,
on the shipped office map and on a small room made here; checked on the map, none wrong."""
import math

import numpy as np
import pytest

from conftest import seeded_office_scans, small_room
from global_loc.core.localizer import Localizer
from global_loc.core.matchers.base import MatchOptions
from global_loc.core.matchers.point_features import PointFeatureOptions, point_features, rigid_fit
from global_loc.core.scan import scan_to_points
from global_loc.core.transform import Rigid2D, pose_correct
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import sample_free_poses, simulate_scan


def right_and_confident(results, truths) -> list[bool]:
    return [r.success and pose_correct(r.pose, t) for r, t in zip(results, truths, strict=True)]


@pytest.fixture(scope='module')
def office():
    office_map, scans = seeded_office_scans(6)
    return Localizer(office_map), scans


def test_features_find_office_poses_the_thesis_features_miss(office):
    localizer, scans = office
    ours = [localizer.localize(scan, 'features') for scan, _ in scans]
    thesis = [localizer.localize(scan, 'features_orb') for scan, _ in scans]
    truths = [t for _, t in scans]
    right = right_and_confident(ours, truths)
    assert sum(right) >= 5, [r.message for r in ours]
    assert not any(right_and_confident(thesis, truths)), [r.message for r in thesis]
    assert all(ok or not r.success for ok, r in zip(right, ours, strict=True))     # never confidently wrong


def test_features_find_poses_in_a_small_room_the_thesis_features_miss():
    room = small_room()
    localizer = Localizer(room)
    rng = np.random.default_rng(3)
    poses = sample_free_poses(room, 6, rng, clearance=0.4)
    laser = LaserConfig(270.0, 541, range_max=8.0, noise_std=0.01, dropout=0.0)
    scans = [simulate_scan(room, pose, laser, rng=rng) for pose in poses]
    proposed = [localizer.matcher('features').match(scan_to_points(s), MatchOptions()).candidates for s in scans]
    assert sum(bool(c) and pose_correct(c[0].laser_pose, p) for c, p in zip(proposed, poses, strict=True)) >= 5
    ours = right_and_confident([localizer.localize(s, 'features') for s in scans], poses)
    thesis = right_and_confident([localizer.localize(s, 'features_orb') for s in scans], poses)
    assert sum(ours) >= 4 and sum(thesis) < sum(ours), (ours, thesis)


def test_a_keypoint_turns_and_moves_with_the_points():
    """The descriptor is read in the keypoint's own frame: the same points turned and moved
    give keypoints at the moved places (within the contour's 0.1 m thinning), orientations
    turned by the same angle, near-equal descriptors, and the fit recovers the motion."""
    rng = np.random.default_rng(0)
    corner = np.vstack([np.column_stack([np.linspace(0, 3, 31), np.zeros(31)]),
                        np.column_stack([np.zeros(20), np.linspace(0.1, 2, 20)]),
                        rng.uniform(-0.1, 0.1, (1, 2)) + [2.0, 1.5]])
    moved = Rigid2D(4.0, -1.0, math.radians(73))
    o = PointFeatureOptions()
    a, b = point_features(corner, False, o), point_features(moved.apply(corner), False, o)
    gap = np.hypot(*(moved.apply(a.xy)[:, None] - b.xy[None]).transpose(2, 0, 1))
    pairs = [(i, int(np.argmin(row))) for i, row in enumerate(gap) if row.min() < 0.25]
    assert len(pairs) >= 3, (a.xy, b.xy)
    ia, ib = np.array(pairs).T
    turned = np.abs(np.angle(np.exp(1j * (b.theta[ib] - a.theta[ia] - moved.yaw))))
    assert np.median(turned) < math.radians(10), np.degrees(turned)
    assert np.median(np.linalg.norm(a.descriptors[ia] - b.descriptors[ib], axis=1)) < 0.4
    fitted = rigid_fit(a.xy[ia], b.xy[ib])
    assert fitted.distance_to(moved)[0] < 0.15 and fitted.distance_to(moved)[1] < math.radians(4)
