"""Several sensors merged into one view (core.view): each sensor's points in the base
frame at its own stamp, moved by odometry to the reference stamp, 3D points cut to the
height band, voxel-filtered once; the sensors left out and why; and the matchers
localizing the result."""
import math

import numpy as np
import pytest

from conftest import assert_pose_near, small_room
from global_loc.core.localizer import Localizer
from global_loc.core.matchers.bnb import BranchAndBoundMatcher
from global_loc.core.mount3d import Mount3D, Mount3DError
from global_loc.core.pose_history import PoseHistory
from global_loc.core.scan import scan_to_points, voxel_filter
from global_loc.core.transform import Rigid2D
from global_loc.core.view import SensorReading, ViewConfig, ViewError, merge_view, reading_from_scan
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import simulate_scan

FRONT = Mount3D(0.16, 0.0, 0.30)
REAR = Mount3D(-0.22, 0.0, 0.30, 0.0, 0.0, math.pi)
# An office pose where a 100-degree laser at the front alone and one at the back alone
# are each ambiguous, and both together localize it confidently (found by a sweep).
TWO_LASER_POSE = Rigid2D(6.975, 14.825, 2.4987)


@pytest.fixture(scope='module')
def office_localizer(office_map):
    return Localizer(office_map)


def laser_reading(occupancy_map, truth, mount, name='scan', fov=270.0, beams=541, seed=0, stamp=0.0):
    scan = simulate_scan(occupancy_map, truth * mount.upright(),
                         LaserConfig(fov, beams, range_max=8.0, noise_std=0.01, dropout=0.0),
                         rng=np.random.default_rng(seed))
    scan.stamp = stamp
    return reading_from_scan(name, scan, mount)


def test_mount3d_puts_sensor_points_on_the_base_any_way_up():
    upside_down = Mount3D(1.0, 0.0, 0.5, math.pi, 0.0, 0.0)
    assert np.allclose(upside_down.apply([[2.0, 1.0]]), [[3.0, -1.0, 0.5]])
    assert upside_down.is_level() and upside_down.upright() == Rigid2D(1.0, 0.0, 0.0)
    assert np.allclose(upside_down.base_angles([0.3]), [-0.3])
    turned = Mount3D(0.0, 0.0, 0.0, 0.0, 0.0, math.pi / 2)
    assert np.allclose(turned.apply([[1.0, 0.0, 2.0]]), [[0.0, 1.0, 2.0]])
    pitched = Mount3D(0.0, 0.0, 1.0, 0.0, math.radians(30), 0.0)     # nose down
    assert not pitched.is_level()
    assert np.allclose(pitched.apply([[1.0, 0.0, 0.0]]), [[math.cos(math.radians(30)), 0.0, 0.5]])
    assert Mount3D.from_values(['1', 2, 3, 0, 0, 0.5]) == Mount3D(1, 2, 3, 0, 0, 0.5)
    for bad in ([1, 2, 3], [1, 2, 3, 4, 5, 'x'], None):
        with pytest.raises(Mount3DError, match='six numbers'):
            Mount3D.from_values(bad)
    with pytest.raises(Mount3DError, match='finite'):
        Mount3D(0, 0, math.nan)


def test_one_level_laser_stays_its_own_scan_and_localizes_as_before(office_map, office_localizer):
    truth = Rigid2D(3.0, 4.0, 0.7)
    mount = Mount3D.planar(Rigid2D(0.16, 0.0, 0.0), z=0.3)
    scan = simulate_scan(office_map, truth * mount.upright(),
                         LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.05),
                         rng=np.random.default_rng(1))
    alone = scan_to_points(scan)
    view = merge_view({'scan': reading_from_scan('scan', scan, mount)}, config=ViewConfig(voxel_size=0.05))
    assert view.points.beams and view.base_T_laser == mount.upright()
    assert np.allclose(view.points.points, alone.points) and view.points.dropped == alone.dropped
    assert np.allclose(view.points.no_return_angles, alone.no_return_angles)
    before = office_localizer.localize(scan, 'bnb', base_T_laser=mount.upright())
    after = office_localizer.localize_points(view.points, 'bnb', base_T_laser=view.base_T_laser)
    assert after.success and after.pose == before.pose and after.score == before.score
    assert_pose_near(after.pose, truth)


def test_an_upside_down_laser_localizes_by_its_mounting(office_map, office_localizer):
    truth = Rigid2D(3.0, 4.0, 0.7)
    mount = Mount3D(0.16, 0.0, 0.3, math.pi, 0.0, 0.0)
    upright = simulate_scan(office_map, truth * mount.upright(),
                            LaserConfig(270.0, 541, range_max=20.0, noise_std=0.0, dropout=0.0))
    upright.ranges = upright.ranges[::-1].copy()       # the same beams, read clockwise
    view = merge_view({'scan': reading_from_scan('scan', upright, mount)})
    result = office_localizer.localize_points(view.points, 'bnb', base_T_laser=view.base_T_laser)
    assert view.points.beams and result.success
    assert_pose_near(result.pose, truth)


def test_two_narrow_lasers_merged_localize_where_each_alone_is_ambiguous(office_map, office_localizer):
    readings = {'/scan': laser_reading(office_map, TWO_LASER_POSE, FRONT, '/scan', 100.0, 201, seed=1),
                '/scan_rear': laser_reading(office_map, TWO_LASER_POSE, REAR, '/scan_rear', 100.0, 201, seed=2)}
    for name, reading in readings.items():
        alone = merge_view({name: reading})
        assert not office_localizer.localize_points(alone.points, 'bnb', base_T_laser=alone.base_T_laser).success
    view = merge_view(readings)
    assert not view.points.beams and view.base_T_laser == Rigid2D()
    assert set(view.contributed) == {'/scan', '/scan_rear'} and not view.left_out
    assert '/scan (' in view.summary() and '/scan_rear (' in view.summary()
    result = office_localizer.localize_points(view.points, 'bnb', base_T_laser=view.base_T_laser)
    assert result.success
    assert_pose_near(result.pose, TWO_LASER_POSE)


def test_a_thesis_matcher_localizes_a_merged_view(office_map, office_localizer):
    truth = Rigid2D(3.0, 4.0, 0.7)
    view = merge_view({'/scan': laser_reading(office_map, truth, FRONT, '/scan', 180.0, 361),
                       '/scan_rear': laser_reading(office_map, truth, REAR, '/scan_rear', 180.0, 361)})
    result = office_localizer.localize_points(view.points, 'template_ccoeff', base_T_laser=view.base_T_laser)
    assert any(h.pose.distance_to(truth)[0] < 0.3 for h in result.hypotheses[:3])


def world_points_seen(base: Rigid2D, mount: Mount3D, world_xy: np.ndarray) -> np.ndarray:
    """`world_xy` (on the floor plane at the sensor's height) in a level sensor's frame."""
    return (base * mount.upright()).inverse().apply(world_xy)


def test_odometry_moves_each_reading_to_the_reference_stamp():
    # Turning at 1 rad/s while driving 0.5 m/s; the rear scan is 50 ms older than the front one.
    odometry = PoseHistory()
    for i in range(11):
        t = i * 0.01
        odometry.add(100.0 + t, Rigid2D(0.5 * t, 0.0, 1.0 * t))
    world = np.random.default_rng(0).uniform(-5, 5, (200, 2))
    front_base, rear_base = odometry.at(100.1), odometry.at(100.05)
    readings = {'front': SensorReading('front', 100.1, world_points_seen(front_base, FRONT, world), FRONT),
                'rear': SensorReading('rear', 100.05, world_points_seen(rear_base, REAR, world), REAR)}
    config = ViewConfig(voxel_size=0.0)
    expected = front_base.inverse().apply(world)
    for source in (odometry, odometry.at):        # a PoseHistory or a stamp -> pose callable
        view = merge_view(readings, source, config=config)
        assert view.stamp == 100.1 and view.motion_compensated
        assert np.abs(np.sort(view.points.points, axis=0) - np.sort(np.vstack([expected, expected]), axis=0)).max() \
            < 1e-9
    smeared = merge_view(readings, None, config=config)
    assert not smeared.motion_compensated and 'not motion-compensated' in smeared.summary()
    rear_points = smeared.points.points[np.argsort(np.arctan2(*smeared.points.points.T[::-1]))]
    assert np.abs(np.sort(rear_points, axis=0) - np.sort(np.vstack([expected, expected]), axis=0)).max() > 0.05


def test_one_laser_moved_to_a_later_stamp_keeps_its_beams_in_its_own_frame():
    odometry = PoseHistory()
    odometry.add(0.0, Rigid2D())
    odometry.add(1.0, Rigid2D(1.0, 0.0, 0.5))
    world = np.random.default_rng(1).uniform(-5, 5, (50, 2))
    scan_base = odometry.at(0.2)
    view = merge_view({'front': SensorReading('front', 0.2, world_points_seen(scan_base, FRONT, world), FRONT)},
                      odometry, reference_stamp=0.6, config=ViewConfig(voxel_size=0.0))
    assert view.points.beams and view.stamp == 0.6
    # the view's frame on the base at 0.6 is where the laser was at 0.2
    assert np.allclose(view.base_T_laser.apply(view.points.points), odometry.at(0.6).inverse().apply(world))


def reading(name, stamp, received=None, points=None, mount=FRONT):
    pts = np.array([[1.0, 0.0], [0.0, 1.0], [2.0, 2.0]]) if points is None else points
    return SensorReading(name, stamp, pts, mount, received=received)


def test_sensors_left_out_silent_too_old_and_clocks_far_apart():
    view = merge_view({'front': reading('front', 50.0, received=50.01),
                       'rear': reading('rear', 49.97, received=50.0),
                       'old': reading('old', 49.0, received=49.0),
                       'skewed': reading('skewed', 1e9, received=50.0),
                       'silent': None}, config=ViewConfig(voxel_size=0.0))
    assert set(view.contributed) == {'front', 'rear'} and view.stamp == 50.0
    assert view.left_out['silent'].startswith('silent')
    assert view.left_out['old'].startswith('too old: its newest reading arrived 1.010 s before')
    assert view.left_out['skewed'].startswith('clocks far apart')
    assert all(f'{s}:' in view.summary() for s in ('silent', 'old', 'skewed'))


def test_the_clocks_most_sensors_agree_on_win_even_when_the_odd_one_arrived_last():
    view = merge_view({'a': reading('a', 10.0, received=10.0), 'b': reading('b', 10.0, received=10.01),
                       'c': reading('c', 99.0, received=10.02)})
    assert set(view.contributed) == {'a', 'b'} and "+88.990 s off b" in view.left_out['c']


def test_no_sensor_contributing_is_an_error_with_each_reason():
    with pytest.raises(ViewError, match='no sensor contributed.*front: silent.*rear: no usable point'):
        merge_view({'front': None, 'rear': reading('rear', 0.0, points=np.full((5, 2), np.nan))})
    with pytest.raises(ViewError, match='no sensor given'):
        merge_view({})


def test_bad_readings_and_options_are_refused():
    with pytest.raises(ViewError, match=r'bad: points must be an \(N, 2\) or \(N, 3\) array'):
        merge_view({'bad': reading('bad', 0.0, points=np.zeros((4, 4)))})
    with pytest.raises(ViewError, match='not finite'):
        merge_view({'bad': reading('bad', math.inf)})
    with pytest.raises(ValueError, match='cloud_z_min < cloud_z_max'):
        ViewConfig(cloud_z_min=1.0, cloud_z_max=0.5)
    with pytest.raises(ValueError, match='merge_window_s'):
        ViewConfig(merge_window_s=-1.0)


def test_a_cloud_is_cut_to_the_height_band_in_the_base_frame():
    lidar = Mount3D(0.0, 0.0, 1.0, 0.0, math.radians(10), 0.0)      # tilted nose down by 10 deg
    wall = np.column_stack([np.full(20, 3.0), np.linspace(-1, 1, 20), np.zeros(20)])     # at the lidar's height
    floor = np.column_stack([np.linspace(1, 2, 10), np.zeros(10), np.zeros(10)])
    floor = (floor - [0.0, 0.0, 1.0]) @ lidar.rotation()        # base z = 0 seen from the lidar
    ceiling = np.array([[2.0, 0.0, 5.0]])
    junk = np.array([[np.nan, 0.0, 0.0], [np.inf, 1.0, 1.0], [1e6, 0.0, 0.0]])
    cloud = SensorReading('/points', 0.0, np.vstack([wall, floor, ceiling, junk]), lidar)
    view = merge_view({'/points': cloud, '/scan': None}, config=ViewConfig(voxel_size=0.0))
    assert view.contributed == {'/points': 20} and not view.points.beams
    assert np.allclose(np.sort(view.points.points[:, 1]), np.sort(lidar.apply(wall)[:, 1]))
    assert view.points.dropped == {'/points.nan_or_inf': 2, '/points.beyond_reach': 1,
                                   '/points.below_cloud_z_min': 10, '/points.above_cloud_z_max': 1}


def test_the_voxel_filter_keeps_what_bnb_would_keep():
    m = small_room()
    points = np.random.default_rng(2).uniform(-2, 2, (200, 2))
    filtered = voxel_filter(points, m.resolution)
    assert len(filtered) < len(points)
    cells = np.floor(filtered / m.resolution)
    assert len(np.unique(cells, axis=0)) == len(filtered)
    matcher = BranchAndBoundMatcher(m)
    assert np.array_equal(matcher.prepare(filtered), matcher.prepare(points))
    assert voxel_filter(points, 0.0) is points


def test_a_tilted_laser_is_cut_to_the_height_band_and_a_level_one_is_not():
    ranges = np.array([1.0, 2.0, 3.0])
    points = np.column_stack([ranges, np.zeros(3)])
    tilted = Mount3D(0.0, 0.0, 0.5, 0.0, math.radians(14.0), 0.0)     # its 2 m beam reaches the floor
    view = merge_view({'scan': SensorReading('scan', 0.0, points, tilted)}, config=ViewConfig(voxel_size=0.0))
    assert len(view.points.points) == 1 and view.points.dropped == {'below_cloud_z_min': 2}
    assert not view.points.beams
    low = Mount3D(0.0, 0.0, 0.05)           # a level laser below cloud_z_min keeps every point
    assert len(merge_view({'scan': SensorReading('scan', 0.0, points, low)}).points.points) == 3
