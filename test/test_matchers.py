"""Each matcher recovers known poses: from local maps cut from the map (thesis §4.1) and,
for the rotated template, from scans ray-cast in the map."""
import math

import cv2
import numpy as np
import pytest

from conftest import assert_pose_near
from global_loc.core.localizer import Localizer, LocalizerConfig
from global_loc.core.matchers import Candidate, MatchOptions, MethodError, method_names, resolve_method
from global_loc.core.matchers.base import distinct
from global_loc.core.matchers.features import FeatureMatcher, make_detector, surf_available
from global_loc.core.outcome import Outcome
from global_loc.core.scan import ScanError
from global_loc.core.transform import Rigid2D
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import points_cut_from_map, simulate_scan

# Distinctive places of the office map (furniture in view), with headings off the grid.
KNOWN_POSES = [Rigid2D(12.0, 8.0, -2.0), Rigid2D(20.0, 12.5, 2.5)]


@pytest.fixture(scope='module')
def localizer(office_map):
    return Localizer(office_map)


@pytest.mark.parametrize('method', ['template_ccoeff', 'template_sqdiff', 'features_orb', 'features_sift'])
@pytest.mark.parametrize('truth', KNOWN_POSES, ids=str)
def test_matcher_recovers_pose_of_local_map_cut_from_the_map(localizer, method, truth):
    points = points_cut_from_map(localizer.map, truth, radius=6.0)
    candidates = localizer.matcher(method).match(points, MatchOptions()).candidates
    assert candidates, f'{method} found nothing'
    assert_pose_near(candidates[0].laser_pose, truth)


@pytest.mark.parametrize('detector', ['orb', 'sift'])
def test_feature_matcher_answers_the_same_whatever_drew_from_opencvs_rng_before(office_map, detector):
    # the FLANN index draws its hash bits / tree splits from OpenCV's per-thread RNG
    points = points_cut_from_map(office_map, KNOWN_POSES[1], radius=6.0)
    answers = set()
    for seed in (1, 2, 3):
        cv2.setRNGSeed(seed)
        candidates = FeatureMatcher(office_map, detector).match(points, MatchOptions()).candidates
        answers.add(tuple((c.laser_pose, c.score) for c in candidates))
    assert len(answers) == 1


# The thesis method is right only ~60-90% of the time (see the benchmark); these are two
# places where it is, so a regression in the pipeline shows here.
@pytest.mark.parametrize('truth', [Rigid2D(3.0, 4.0, 0.7), Rigid2D(18.0, 4.5, -2.2)], ids=str)
def test_rotated_template_localizes_a_raycast_270_deg_scan(localizer, truth):
    scan = simulate_scan(localizer.map, truth,
                         LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.02),
                         rng=np.random.default_rng(7))
    result = localizer.localize(scan, method='template_ccoeff')
    assert_pose_near(result.pose, truth)
    assert result.outcome == Outcome.LOCALIZED and result.method == 'template_ccoeff'
    assert result.hypotheses[0].pose == result.pose
    assert result.dropped['nan'] > 0          # the dropouts were seen and dropped


def test_result_pose_is_the_base_when_the_laser_is_mounted_forward(office_map):
    truth_base = Rigid2D(3.0, 4.0, 0.7)
    mount = Rigid2D(0.2, 0.0, 0.0)
    scan = simulate_scan(office_map, truth_base * mount,
                         LaserConfig(270.0, 541, range_max=20.0, noise_std=0.0, dropout=0.0),
                         rng=np.random.default_rng(1))
    result = Localizer(office_map, LocalizerConfig(base_T_laser=mount)).localize(scan)
    assert_pose_near(result.pose, truth_base)


def test_hypotheses_are_distinct_in_position_or_heading():
    c = [Candidate(Rigid2D(0, 0, 0), 1.0), Candidate(Rigid2D(0.1, 0, 0.05), 0.9),
         Candidate(Rigid2D(0.1, 0, math.pi), 0.8), Candidate(Rigid2D(5, 0, 0), 0.7)]
    kept = distinct(c, 5, 1.0, math.radians(20))
    assert [k.score for k in kept] == [1.0, 0.8, 0.7]


def test_unknown_method_and_missing_surf_are_clear_errors(localizer):
    with pytest.raises(MethodError, match='unknown method .*known: .*template_ccoeff'):
        resolve_method('magic')
    assert 'features' in method_names()
    if not surf_available():
        with pytest.raises(MethodError, match='SURF is not in this OpenCV build.*features_orb'):
            make_detector('surf')
    assert resolve_method('features') == 'features'      # ours (scan_features.py); the thesis's path by detector


def test_bad_scan_and_bad_angle_step_raise_before_matching(localizer):
    scan = simulate_scan(localizer.map, Rigid2D(3.0, 4.0, 0.0),
                         LaserConfig(270.0, 541, range_max=20.0, noise_std=0.0, dropout=0.0))
    with pytest.raises(ValueError, match='angle step'):
        localizer.localize(scan, angle_step_deg=-5)
    scan.ranges[:] = np.nan
    with pytest.raises(ScanError):
        localizer.localize(scan)
