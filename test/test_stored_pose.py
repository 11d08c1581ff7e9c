"""Start-up from the last pose (core/stored_pose.py): the file is written atomically and read
back exactly or refused with the reason; a robot that was not moved is confirmed by the
scan's fit at the stored pose, and a robot moved off it, carried to another map, a stale
file or a map set that grew are never confirmed (the caller then searches in full)."""
import json
import math
import os

import numpy as np
import pytest

from conftest import assert_pose_near, seeded_office_scans
from global_loc.core.localizer import Localizer
from global_loc.core.map_io import make_map
from global_loc.core.map_set import MapSet
from global_loc.core.scan import scan_to_points
from global_loc.core.stored_pose import (
    SinceStored,
    StoredPose,
    StoredPoseError,
    confirm_stored_pose,
    load_stored_pose,
    save_stored_pose,
    stored_from_result,
)
from global_loc.core.transform import Rigid2D
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import sample_free_poses, simulate_scan

LASER = LaserConfig(270, 541, range_max=20.0, noise_std=0.01, dropout=0.0)


@pytest.fixture(scope='module')
def office_set():
    office, scans = seeded_office_scans(4)
    mirror = make_map(np.flipud(office.occupancy).copy(), office.resolution, office.origin, 'mirror')
    maps = MapSet({'office': Localizer(office), 'mirror': Localizer(mirror)})
    stored = []
    for scan, truth in scans:
        result = maps.localize(scan)
        if result.success:
            stored.append((stored_from_result(result, maps.names, 1000.0, Rigid2D(1.0, 2.0, 0.5)), truth))
    assert len(stored) >= 2
    return maps, office, mirror, stored


def test_the_file_is_written_atomically_and_read_back_exactly(tmp_path, office_set):
    stored = office_set[3][0][0]
    path = str(tmp_path / 'state' / 'pose.json')
    save_stored_pose(path, stored)
    assert load_stored_pose(path) == stored
    assert os.listdir(tmp_path / 'state') == ['pose.json']        # no temporary file left
    save_stored_pose(path, StoredPose('office', ('office',), Rigid2D(1, 2, 3), 0.9, 0.8, (0.0,) * 9, 5.0))
    assert load_stored_pose(path).pose == Rigid2D(1, 2, 3)


def test_a_bad_file_is_refused_with_the_reason(tmp_path):
    path = tmp_path / 'pose.json'
    with pytest.raises(StoredPoseError, match='none saved yet'):
        load_stored_pose(str(path))
    good = StoredPose('office', ('office',), Rigid2D(1, 2, 3), 0.9, 0.8, (0.0,) * 9, 5.0).as_dict()
    for broken, says in (('{', 'cannot be read'), ('[1]', 'not an object'),
                         (json.dumps({**good, 'format': 'x'}), 'format'),
                         (json.dumps({**good, 'pose': [1, 'a', 2]}), 'malformed'),
                         (json.dumps({**good, 'fit': float('nan')}), 'finite'),
                         (json.dumps({**good, 'covariance': [0, 0]}), '9 numbers')):
        path.write_text(broken)
        with pytest.raises(StoredPoseError, match=says):
            load_stored_pose(str(path))


def test_a_robot_that_was_not_moved_is_confirmed_on_its_map(office_set):
    maps, office, _, stored = office_set
    rng = np.random.default_rng(11)
    by_odometry = 0
    for pose, truth in stored:
        points = scan_to_points(simulate_scan(office, truth, LASER, rng=rng))     # a new scan, same place
        result, why = confirm_stored_pose(maps, points, pose, Rigid2D(), SinceStored(60.0))
        assert result is not None and result.success, why
        assert result.map == 'office' and result.hypotheses[0].map == 'office'
        assert 'the stored pose confirmed (stored;' in result.message
        assert_pose_near(result.pose, truth)
        # odometry that ran on: the stored pose is moved by it first
        moved = Rigid2D(truth.x + 0.3 * math.cos(truth.yaw), truth.y + 0.3 * math.sin(truth.yaw), truth.yaw)
        if office.is_free_at(np.array([[moved.x, moved.y]]))[0]:
            points = scan_to_points(simulate_scan(office, moved, LASER, rng=rng))
            odometry_now = pose.odometry * (truth.inverse() * moved)
            result, why = confirm_stored_pose(maps, points, pose, Rigid2D(), SinceStored(60.0, odometry_now))
            assert result is not None and 'moved by odometry' in result.message, why
            assert_pose_near(result.pose, moved)
            by_odometry += 1
    assert by_odometry >= 1


def test_a_moved_or_carried_robot_a_stale_file_or_a_new_map_is_not_confirmed(office_set):
    maps, office, mirror, stored = office_set
    rng = np.random.default_rng(12)
    pose, truth = stored[0]
    far = next(p for p, _ in stored[1:] if p.pose.distance_to(truth)[0] > 2.0) if len(stored) > 1 else None
    cases = [('carried to the mirror', mirror, sample_free_poses(mirror, 1, rng, clearance=0.5)[0])]
    if far is not None:
        cases.append(('carried across the office', office, far.pose))
    for label, where, at in cases:
        points = scan_to_points(simulate_scan(where, at, LASER, rng=rng))
        result, why = confirm_stored_pose(maps, points, pose, Rigid2D(), SinceStored(60.0))
        assert result is None and 'does not confirm' in why, label
    points = scan_to_points(simulate_scan(office, truth, LASER, rng=rng))
    assert 'stale' in confirm_stored_pose(maps, points, pose, Rigid2D(), SinceStored(7200.0), max_age_s=3600.0)[1]
    # stamped a year in the future (the clock went back): an age that cannot be known is stale
    future = confirm_stored_pose(maps, points, pose, Rigid2D(), SinceStored(-31536000.0), max_age_s=3600.0)
    assert future[0] is None and 'stamped 31536000 s in the future' in future[1]
    grown = MapSet({**maps.localizers, 'annex': maps.localizers['mirror']})
    assert 'map annex was not searched then' in confirm_stored_pose(grown, points, pose, Rigid2D(), SinceStored(1.0))[1]
    other = StoredPose('floor_9', ('floor_9',), truth, pose.fit, 1.0, (0.0,) * 9, 0.0)
    assert 'not served' in confirm_stored_pose(maps, points, other, Rigid2D(), SinceStored(1.0))[1]


def test_only_a_confident_answer_is_stored(office_set):
    maps, office, _, _ = office_set
    floors = MapSet({'floor_1': maps.localizers['office'], 'floor_2': maps.localizers['office']})
    scan, _ = seeded_office_scans(1)[1][0]
    ambiguous = floors.localize(scan)
    assert not ambiguous.success
    with pytest.raises(StoredPoseError, match='only a confident answer'):
        stored_from_result(ambiguous, floors.names, 0.0)
