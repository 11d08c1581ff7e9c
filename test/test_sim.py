"""The pybullet simulator through its Python API (no ROS)."""
import math

import numpy as np
import pytest

from conftest import grid_map, walled
from global_loc.core.localizer import Localizer
from global_loc.core.transform import Rigid2D
from global_loc.core.view import SensorReading, merge_view, reading_from_scan
from global_loc.sim.laser import LaserConfig
from global_loc.sim.lidar3d import Lidar3DConfig
from global_loc.sim.raycast import simulate_scan
from global_loc.sim.robot import LIDAR_MOUNT
from global_loc.sim.simulator import (
    BASE_T_LASER,
    BASE_T_REAR_LASER,
    FRONT_LASER_MOUNT,
    REAR_LASER_MOUNT,
    Simulator,
)
from global_loc.sim.world import merge_cells_into_boxes, obstacle_heights


@pytest.fixture(scope='module')
def sim(office_map):
    s = Simulator(office_map, LaserConfig(noise_std=0.0, dropout=0.0))
    yield s
    s.close()


def test_merged_boxes_cover_exactly_the_occupied_cells(office_map):
    boxes = merge_cells_into_boxes(office_map.occupied)
    covered = np.zeros(office_map.occupied.shape, dtype=int)
    for r0, c0, r1, c1 in boxes:
        covered[r0:r1, c0:c1] += 1
    assert np.array_equal(covered, office_map.occupied.astype(int))
    assert len(boxes) < office_map.occupied.sum() / 50


def test_scan_agrees_with_the_numpy_ray_caster_at_a_teleported_pose(sim, office_map):
    truth = Rigid2D(18.0, 4.5, -2.2)
    sim.place(truth)
    assert sim.true_pose().distance_to(truth)[0] < 1e-6
    scan = sim.scan()
    reference = simulate_scan(office_map, truth * BASE_T_LASER,
                              LaserConfig(270.0, 541, range_max=20.0, noise_std=0.0, dropout=0.0))
    both = np.isfinite(scan.ranges) & np.isfinite(reference.ranges)
    assert both.mean() > 0.95
    # pybullet hits the wall surface, the ray caster the cell it marches into: < 1-2 cells apart.
    assert np.median(np.abs(scan.ranges[both] - reference.ranges[both])) < 0.05


def test_wheels_turn_and_drive_the_robot(sim):
    sim.place(Rigid2D(3.0, 4.0, 0.0))
    sim.drive(0.0, 0.5, 2.0)
    turned = sim.true_pose()
    assert math.degrees(turned.yaw) == pytest.approx(math.degrees(1.0), abs=12)
    sim.drive(0.3, 0.0, 2.0)
    moved = sim.true_pose()
    assert math.hypot(moved.x - turned.x, moved.y - turned.y) == pytest.approx(0.6, abs=0.1)


def test_clutter_shows_in_the_scan(office_map):
    s = Simulator(office_map, LaserConfig(noise_std=0.0, dropout=0.0))
    try:
        pose = Rigid2D(12.0, 8.0, 0.0)
        s.place(pose)
        before = s.scan().ranges
        from global_loc.sim.simulator import ClutterObject
        s.add_clutter([ClutterObject(13.5, 8.0, (0.25,))])     # a person 1.34 m ahead of the laser
        after = s.scan().ranges
        ahead = len(after) // 2
        # Bullet pads convex shapes such as cylinders with its ~0.04 m collision margin.
        assert after[ahead] == pytest.approx(1.5 - 0.16 - 0.25, abs=0.06)
        assert before[ahead] > 5
    finally:
        s.close()


def test_noise_and_dropout(office_map):
    s = Simulator(office_map, LaserConfig(noise_std=0.02, dropout=0.1), seed=3)
    try:
        s.place(Rigid2D(3.0, 4.0, 0.7))
        ranges = s.scan().ranges
        assert 0.05 < np.isnan(ranges).mean() < 0.16
    finally:
        s.close()


# ---- optional sensors: the rear laser and the 3D lidar in a world extruded in 3D ------------
def test_obstacle_heights_give_walls_pillars_and_furniture_their_own(office_map):
    heights = obstacle_heights(office_map)
    assert np.array_equal(heights > 0, office_map.occupied)
    assert set(np.unique(heights[office_map.occupied])) == {0.7, 1.2, 2.5}
    largest = heights == 2.5
    assert largest.sum() > 0.5 * office_map.occupied.sum()      # the building's walls


def test_the_default_world_is_the_2d_one(office_map):
    s = Simulator(office_map)
    try:
        assert s.rear_laser is None and s.lidar is None
        with pytest.raises(RuntimeError, match='no rear laser'):
            s.rear_scan()
        with pytest.raises(RuntimeError, match='no 3D lidar'):
            s.lidar_points()
    finally:
        s.close()


@pytest.fixture(scope='module')
def office_localizer(office_map):
    return Localizer(office_map)


@pytest.fixture(scope='module')
def sim3d(office_map):
    s = Simulator(office_map, LaserConfig(noise_std=0.0, dropout=0.0), rear_laser=LaserConfig(noise_std=0.0,
                  dropout=0.0), lidar=Lidar3DConfig(noise_std=0.0))
    yield s
    s.close()


def test_rear_laser_looks_back_from_its_mounting(sim3d, office_map):
    truth = Rigid2D(18.0, 4.5, -2.2)
    sim3d.place(truth)
    rear = sim3d.rear_scan()
    reference = simulate_scan(office_map, truth * BASE_T_REAR_LASER,
                              LaserConfig(270.0, 541, range_max=20.0, noise_std=0.0, dropout=0.0))
    both = np.isfinite(rear.ranges) & np.isfinite(reference.ranges)
    assert both.mean() > 0.95
    assert np.median(np.abs(rear.ranges[both] - reference.ranges[both])) < 0.05
    assert REAR_LASER_MOUNT.upright() == BASE_T_REAR_LASER


def lidar_in_base(sim) -> np.ndarray:
    """The lidar's points in the base frame, ring by ring (rings, columns, 3)."""
    points = sim.lidar_points()
    return LIDAR_MOUNT.apply(points.reshape(-1, 3)).reshape(points.shape)


def test_lidar_rings_see_walls_to_their_top_and_the_floor(sim3d, office_map):
    cfg = sim3d.lidar
    assert np.allclose(np.degrees(cfg.elevations()[[0, -1]]), [-15, 15]) and cfg.rings == 16
    sim3d.place(Rigid2D(12.0, 8.0, 0.3))
    points = lidar_in_base(sim3d)
    assert points.shape == (16, cfg.columns, 3)
    lowest = points[0][np.isfinite(points[0, :, 2])]
    # the lowest ring (-15 deg from 0.5 m) hits the floor ~1.87 m around the robot (but where a pillar
    # or furniture is nearer)
    floor = np.abs(lowest[:, 2]) < 0.02
    assert floor.mean() > 0.5 and np.median(np.hypot(lowest[floor, 0], lowest[floor, 1])) == \
        pytest.approx(0.5 / math.tan(math.radians(15)), abs=0.05)
    top = points[-1][np.isfinite(points[-1, :, 2])]
    assert top[:, 2].max() <= 2.5 + 1e-6 and top[:, 2].max() > 2.0    # walls end at 2.5 m


def test_a_low_table_is_seen_only_by_the_lower_rings():
    room = walled(120, 160)                 # 8 x 6 m at 5 cm
    room[50:70, 100:112] = 100              # a table 1 x 0.6 m, 2 m ahead of the robot at (3, 3)
    m = grid_map(room)
    heights = obstacle_heights(m)
    assert heights[60, 105] == 0.7 and heights[0, 0] == 2.5
    s = Simulator(m, lidar=Lidar3DConfig(noise_std=0.0))
    try:
        s.place(Rigid2D(3.0, 3.0, 0.0))
        ahead = lidar_in_base(s)[:, s.lidar.columns // 2]       # the column at azimuth 0
        on_table = np.abs(ahead[:, 0] - 2.0) < 0.05
        elevations = np.degrees(s.lidar.elevations())
        assert on_table.any() and (elevations[on_table] < 5.5).all()      # lower rings only
        over = ~on_table & (elevations > 5.5)
        assert over.sum() >= 4 and (ahead[over, 0] > 4.9).all()      # the upper rings pass over it to the far wall
    finally:
        s.close()


def test_the_lidar_view_localizes_in_the_office(sim3d, office_localizer):
    truth = Rigid2D(3.0, 4.0, 0.7)
    sim3d.place(truth)
    reading = SensorReading('/points', 0.0, sim3d.lidar_points().reshape(-1, 3), LIDAR_MOUNT)
    view = merge_view({'/points': reading})
    assert view.points.dropped['below_cloud_z_min'] > 500       # the floor
    result = office_localizer.localize_points(view.points, 'bnb', base_T_laser=view.base_T_laser)
    assert result.success and result.pose.distance_to(truth)[0] < 0.2


def test_front_and_rear_lasers_merged_localize(sim3d, office_localizer):
    truth = Rigid2D(6.975, 14.825, 2.4987)
    sim3d.place(truth)
    view = merge_view({'/scan': reading_from_scan('/scan', sim3d.scan(), FRONT_LASER_MOUNT),
                       '/scan_rear': reading_from_scan('/scan_rear', sim3d.rear_scan(), REAR_LASER_MOUNT)})
    result = office_localizer.localize_points(view.points, 'bnb', base_T_laser=view.base_T_laser)
    assert result.success and result.pose.distance_to(truth)[0] < 0.2


@pytest.mark.ros
def test_sim_node_publishes_the_rear_laser_and_the_lidar_when_enabled(tmp_path):
    from sensor_msgs.msg import LaserScan, PointCloud2

    from global_loc.ros.cloud import cloud_from_msg
    from global_loc.testing.processes import TopicRecorder, isolated_env, reliable, start_sim
    env = isolated_env()
    sim = start_sim(env, tmp_path / 'sim.log', 'rear_laser:=true', 'lidar3d:=true', 'x:=3.0', 'y:=4.0', 'yaw:=0.7')
    recorder = TopicRecorder(env, {'/scan_rear': (LaserScan, reliable(5)), '/points': (PointCloud2, reliable(2)),
                                   '/scan': (LaserScan, reliable(5))})
    try:
        rear = recorder.wait_for('/scan_rear', 1, timeout=20.0)
        clouds = recorder.wait_for('/points', 1, timeout=20.0)
        assert rear and clouds, sim.output()
        assert rear[0].header.frame_id == 'laser_rear' and len(rear[0].ranges) == 541
        assert math.degrees(rear[0].angle_max - rear[0].angle_min) == pytest.approx(270.0)
        cloud = clouds[0]
        assert cloud.header.frame_id == 'lidar' and (cloud.height, cloud.width) == (16, Lidar3DConfig().columns)
        points = cloud_from_msg(cloud)
        assert points.shape == (16 * cloud.width, 3) and np.isfinite(points).all(axis=1).mean() > 0.9
        assert 'rear laser on /scan_rear' in sim.output() and '3D lidar on /points' in sim.output()
    finally:
        recorder.close()
        sim.stop()
    plain = start_sim(env, tmp_path / 'plain.log')
    recorder = TopicRecorder(env, {'/scan': (LaserScan, reliable(5))}, node_name='plain_recorder')
    try:
        assert recorder.wait_for('/scan', 1, timeout=20.0)
        assert recorder.node.count_publishers('/scan_rear') == 0 and recorder.node.count_publishers('/points') == 0
    finally:
        recorder.close()
        plain.stop()


def test_the_shipped_sim_params_give_the_simulators_own_mountings():
    """config/sim.yaml is what tells the server (without tf2) where the simulator's sensors sit."""
    import yaml

    from global_loc.core.mount3d import Mount3D
    from global_loc.core.paths import sim_params_file
    from global_loc.sim.simulator import BASE_T_LASER, LASER_HEIGHT, REAR_LASER_MOUNT
    with open(sim_params_file()) as f:
        sensors = yaml.safe_load(f)['global_loc_server']['ros__parameters']['sensors']
    mounts = {name: Mount3D.from_values(value['mount']) for name, value in sensors.items()}
    assert mounts == {'scan': Mount3D.planar(BASE_T_LASER, LASER_HEIGHT), 'scan_rear': REAR_LASER_MOUNT,
                      'points': LIDAR_MOUNT}
