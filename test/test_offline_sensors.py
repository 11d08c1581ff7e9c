"""`python -m global_loc localize --bag --topic A --topic B --cloud-topic C`:
a recording's sensors merged into one view as the server merges them - each one's
mounting from the bag's /tf_static (or --mount), clouds parsed from the recorded
PointCloud2 by the core parser, the bag's odometry when it has one - and one line per
view saying which sensors contributed and which were left out and why."""
import json
import math

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from test_bag import TYPES, laser_scan, run_cli, transform

from conftest import assert_pose_near, needs_pybullet
from global_loc.core.cloud import pack_cloud
from global_loc.core.transform import Rigid2D
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import simulate_scan
from global_loc.sim.robot import LIDAR_MOUNT

TF = 'tf2_msgs/msg/TFMessage'
SCAN = 'sensor_msgs/msg/LaserScan'
CLOUD = 'sensor_msgs/msg/PointCloud2'
FRONT = Rigid2D(0.16, 0.0, 0.0)
REAR = Rigid2D(-0.22, 0.0, math.pi)
# An office pose where a 100-degree laser at the front alone and one at the back alone are
# each not confident, both together confident (test_view, test_sensors).
TWO_LASER_POSE = Rigid2D(6.975, 14.825, 2.4987)


def write(writer, connection, sec: float, msg, msgtype):
    writer.write(connection, int(sec * 1e9), TYPES.serialize_cdr(msg, msgtype))


def tf_static(writer, *transforms):
    write(writer, writer.add_connection('/tf_static', TF, typestore=TYPES), 99.0,
          TYPES.types[TF](transforms=list(transforms)), TF)


def odometry(sec: float, pose: Rigid2D):
    m = TYPES.types
    stamp = m['builtin_interfaces/msg/Time'](sec=int(sec), nanosec=int(round((sec % 1) * 1e9)))
    pose_msg = m['geometry_msgs/msg/Pose'](position=m['geometry_msgs/msg/Point'](x=pose.x, y=pose.y, z=0.0),
                                           orientation=m['geometry_msgs/msg/Quaternion'](
                                               x=0.0, y=0.0, z=math.sin(pose.yaw / 2), w=math.cos(pose.yaw / 2)))
    return m['nav_msgs/msg/Odometry'](
        header=m['std_msgs/msg/Header'](stamp=stamp, frame_id='odom'), child_frame_id='base_link',
        pose=m['geometry_msgs/msg/PoseWithCovariance'](pose=pose_msg, covariance=np.zeros(36)),
        twist=m['geometry_msgs/msg/TwistWithCovariance'](twist=m['geometry_msgs/msg/Twist'](
            linear=m['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0),
            angular=m['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0)), covariance=np.zeros(36)))


def write_two_laser_bag(path, office_map):
    """Two 100-degree lasers at TWO_LASER_POSE, front and rear, mounted on /tf_static; the
    rear one's scans 50 ms after the front's, and its last scan 2 s before the last front
    one; the robot standing still on /odom; and /scan_side, which tf does not mount."""
    rng = np.random.default_rng(1)
    with Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        tf_static(writer, transform('base_link', 'laser', FRONT, 0.3, 99),
                  transform('base_link', 'laser_rear', REAR, 0.3, 99))
        topics = {t: writer.add_connection(t, SCAN, typestore=TYPES) for t in ('/scan', '/scan_rear', '/scan_side')}
        odom = writer.add_connection('/odom', 'nav_msgs/msg/Odometry', typestore=TYPES)
        for sec in (100.0, 101.0, 103.0):
            write(writer, odom, sec, odometry(sec, Rigid2D(1.0, 2.0, 0.3)), 'nav_msgs/msg/Odometry')
        for sec, topic, mount, frame in ((100, '/scan', FRONT, 'laser'), (100.05, '/scan_rear', REAR, 'laser_rear'),
                                         (100.05, '/scan_side', FRONT, 'laser_side'),
                                         (101, '/scan', FRONT, 'laser'), (103, '/scan', FRONT, 'laser')):
            scan = simulate_scan(office_map, TWO_LASER_POSE * mount,
                                 LaserConfig(100.0, 201, range_max=8.0, noise_std=0.01, dropout=0.0), rng=rng)
            msg = laser_scan(scan, int(sec), frame)
            msg.header.stamp.nanosec = int(round((sec % 1) * 1e9))
            write(writer, topics[topic], sec, msg, SCAN)


def rows_of(out) -> list[dict]:
    assert out.returncode == 0, out.stderr
    return [json.loads(line) for line in out.stdout.splitlines()]


@pytest.mark.process
def test_two_narrow_lasers_from_a_bag_localize_merged_where_each_alone_does_not(tmp_path, office_map):
    write_two_laser_bag(tmp_path / 'run', office_map)
    for topic in ('/scan', '/scan_rear'):
        alone = rows_of(run_cli('--bag', str(tmp_path / 'run'), '--topic', topic))[0]
        assert not alone['success'], alone
    rows = rows_of(run_cli('--bag', str(tmp_path / 'run'), '--topic', '/scan', '--topic', '/scan_rear',
                           '--topic', '/scan_side'))
    assert [r['index'] for r in rows] == [0, 1, 2]
    merged = rows[0]
    assert merged['outcome'] == 'localized' and merged['success'], merged
    assert_pose_near(Rigid2D(merged['x'], merged['y'], merged['yaw']), TWO_LASER_POSE)
    assert set(merged['view']['contributed']) == {'/scan', '/scan_rear'}
    assert merged['view']['left_out']['/scan_side'].startswith('ViewError: no mounting'), merged['view']
    assert merged['view']['motion_compensated'] and merged['odometry'] == '/odom (3 poses)'
    rear = merged['mounting']['/scan_rear']
    assert (rear['from'], rear['frames']) == ('/tf_static', 'base_link -> laser_rear')
    assert (rear['x'], rear['y'], rear['z'], rear['yaw']) == pytest.approx((-0.22, 0.0, 0.3, math.pi), abs=1e-6)
    # 1 s after the rear laser's last scan: too old for the window, said; 3 s: the same
    for row in rows[1:]:
        assert set(row['view']['contributed']) == {'/scan'}, row['view']
        assert row['view']['left_out']['/scan_rear'].startswith('too old'), row['view']
    # a wider window takes the rear scan 1 s older in again (the robot stood still)
    wide = rows_of(run_cli('--bag', str(tmp_path / 'run'), '--topic', '/scan', '--topic', '/scan_rear',
                           '--merge-window', '1.5', '--every', '2'))
    assert set(wide[0]['view']['contributed']) == {'/scan', '/scan_rear'}
    assert [r['index'] for r in wide] == [0, 2]


@pytest.mark.process
def test_flags_that_cannot_be_used_are_clear_errors(tmp_path, office_map):
    write_two_laser_bag(tmp_path / 'run', office_map)
    bag = ('--bag', str(tmp_path / 'run'))
    for flags, said in ((('--topic', '/scan', '--topic', '/scan'), 'a topic is given twice'),
                        (('--topic', '/scan', '--mount', '/points', '0', '0', '0', '0', '0', '0'),
                         '--mount for /points, which is no --topic or --cloud-topic'),
                        (('--topic', '/scan', '--topic', '/scan_rear', '--mount', '/scan_rear', '0', '0', '0', '0',
                          '0', 'x'), '--mount /scan_rear: a mounting needs six numbers'),
                        (('--topic', '/scan', '--cloud-topic', '/scan_rear'), '/scan_rear carries '
                                                                              'sensor_msgs/msg/LaserScan, not '
                                                                              'sensor_msgs/msg/PointCloud2'),
                        (('--topic', '/scan', '--topic', '/scan_rear', '--follow'), '--follow and --plot take one')):
        out = run_cli(*bag, *flags)
        assert out.returncode == 2 and said in out.stderr, (flags, out.stderr)
    out = run_cli('--scans', '-', '--topic', '/scan', '--topic', '/scan_rear')
    assert out.returncode == 2 and 'read a --bag' in out.stderr, out.stderr


def cloud_message(xyz, sec: int, frame: str, point_step=None):
    """A PointCloud2 in the Velodyne layout core.cloud.pack_cloud makes (point_step: a wrong one)."""
    m = TYPES.types
    packed = pack_cloud(xyz)
    fields = [m['sensor_msgs/msg/PointField'](name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
              for f in packed.fields]
    return m[CLOUD](header=m['std_msgs/msg/Header'](stamp=m['builtin_interfaces/msg/Time'](sec=sec, nanosec=0),
                                                     frame_id=frame),
                    height=packed.height, width=packed.width, fields=fields, is_bigendian=packed.is_bigendian,
                    point_step=point_step or packed.point_step, row_step=packed.row_step,
                    data=np.frombuffer(packed.data, np.uint8), is_dense=packed.is_dense)


@needs_pybullet
@pytest.mark.process
def test_the_simulated_lidar_from_a_bag_localizes_and_a_broken_cloud_is_left_out(tmp_path, office_map):
    from global_loc.sim.lidar3d import Lidar3DConfig
    from global_loc.sim.simulator import Simulator
    sim = Simulator(office_map, lidar=Lidar3DConfig())
    try:
        sim.place(Rigid2D(3.0, 4.0, 0.7))
        truth, xyz = sim.true_pose(), sim.lidar_points()
    finally:
        sim.close()
    lidar = Rigid2D(LIDAR_MOUNT.x, LIDAR_MOUNT.y, LIDAR_MOUNT.yaw)
    with Writer(tmp_path / 'run', version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        tf_static(writer, transform('base_link', 'lidar', lidar, LIDAR_MOUNT.z, 99))
        points, bad = (writer.add_connection(t, CLOUD, typestore=TYPES) for t in ('/points', '/points_bad'))
        write(writer, points, 100.0, cloud_message(xyz, 100, 'lidar'), CLOUD)
        write(writer, bad, 100.02, cloud_message(xyz[:2], 100, 'lidar_bad', point_step=12), CLOUD)
    rows = rows_of(run_cli('--bag', str(tmp_path / 'run'), '--cloud-topic', '/points', '--cloud-topic',
                           '/points_bad', '--mount', '/points_bad', '0', '0', '0.5', '0', '0', '0'))
    assert len(rows) == 1
    row = rows[0]
    assert row['outcome'] == 'localized', row
    assert_pose_near(Rigid2D(row['x'], row['y'], row['yaw']), truth)
    assert list(row['view']['contributed']) == ['/points'] and row['odometry'].startswith('none: ')
    assert row['mounting']['/points']['z'] == pytest.approx(0.5) and row['mounting']['/points_bad']['from'] == '--mount'
    assert 'cloud unusable' in row['view']['left_out']['/points_bad'] and 'point_step 12' in \
        row['view']['left_out']['/points_bad'], row['view']
