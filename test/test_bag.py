"""`python -m global_loc localize --bag`: rosbag2 recordings of both storage kinds, written
here with the rosbags library from simulated scans, localized without ROS; recordings
without the topic, or with another type on it, are clear errors. A laser mounted turned and
off-centre: its mounting is read from the bag's /tf_static and fixed /tf transforms, so the
printed poses are the base's, or from the --laser-* flags when the bag has none."""
import json
import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from conftest import OFFICE_YAML
from global_loc.core.transform import Rigid2D, pose_correct
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import simulate_scan

POSES = [Rigid2D(3.0, 4.0, 0.7), Rigid2D(12.0, 8.0, -2.0), Rigid2D(20.0, 12.5, 2.5)]
TYPES = get_typestore(Stores.ROS2_JAZZY)


def laser_scan(scan, sec: int, frame_id='laser'):
    m = TYPES.types
    header = m['std_msgs/msg/Header'](stamp=m['builtin_interfaces/msg/Time'](sec=sec, nanosec=500), frame_id=frame_id)
    angle_max = scan.angle_min + scan.angle_increment * (len(scan.ranges) - 1)
    return m['sensor_msgs/msg/LaserScan'](
        header=header, angle_min=scan.angle_min, angle_max=angle_max, angle_increment=scan.angle_increment,
        time_increment=0.0, scan_time=0.1, range_min=scan.range_min,
        range_max=scan.range_max, ranges=np.asarray(scan.ranges, np.float32), intensities=np.zeros(0, np.float32))


def write_bag(path, storage, office_map, topic='/scan', msgtype='sensor_msgs/msg/LaserScan'):
    rng = np.random.default_rng(3)
    with Writer(path, version=9, storage_plugin=storage) as writer:
        conn = writer.add_connection(topic, msgtype, typestore=TYPES)
        other = writer.add_connection('/chatter', 'std_msgs/msg/String', typestore=TYPES)
        for i, pose in enumerate(POSES):
            scan = simulate_scan(office_map, pose,
                                 LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.0), rng=rng)
            msg = laser_scan(scan, 100 + i) if msgtype.endswith('LaserScan') else TYPES.types[msgtype](data='x')
            writer.write(conn, (100 + i) * 10**9, TYPES.serialize_cdr(msg, msgtype))
            writer.write(other, (100 + i) * 10**9 + 1, TYPES.serialize_cdr(TYPES.types['std_msgs/msg/String'](
                data='noise'), 'std_msgs/msg/String'))


def run_cli(*args):
    return subprocess.run([sys.executable, '-m', 'global_loc', 'localize', '--map', OFFICE_YAML, *args],
                          capture_output=True, text=True, timeout=300)


@pytest.mark.process
@pytest.mark.parametrize('storage', [StoragePlugin.SQLITE3, StoragePlugin.MCAP], ids=['sqlite3', 'mcap'])
def test_bag_scans_are_localized_with_their_stamps(tmp_path, office_map, storage):
    write_bag(tmp_path / 'run', storage, office_map)
    out = run_cli('--bag', str(tmp_path / 'run'), '--topic', '/scan')
    assert out.returncode == 0, out.stderr
    rows = [json.loads(line) for line in out.stdout.splitlines()]
    assert [r['index'] for r in rows] == [0, 1, 2]
    assert [r['stamp'] for r in rows] == pytest.approx([100 + 5e-7, 101 + 5e-7, 102 + 5e-7])
    for row, truth in zip(rows, POSES, strict=True):
        assert row['outcome'] == 'localized', row
        assert pose_correct(Rigid2D(row['x'], row['y'], row['yaw']), truth)
    every = [json.loads(line) for line in run_cli('--bag', str(tmp_path / 'run'), '--every', '2').stdout.splitlines()]
    assert [r['index'] for r in every] == [0, 2]


@pytest.mark.process
def test_bag_without_the_topic_or_with_another_type_is_a_clear_error(tmp_path, office_map):
    write_bag(tmp_path / 'run', StoragePlugin.SQLITE3, office_map)
    out = run_cli('--bag', str(tmp_path / 'run'), '--topic', '/base_scan')
    assert out.returncode == 2 and 'no topic /base_scan; the recording has: /chatter (std_msgs/msg/String), ' \
                                   '/scan (sensor_msgs/msg/LaserScan)' in out.stderr, out.stderr
    write_bag(tmp_path / 'strings', StoragePlugin.MCAP, office_map, msgtype='std_msgs/msg/String')
    out = run_cli('--bag', str(tmp_path / 'strings'))
    assert out.returncode == 2 and '/scan carries std_msgs/msg/String, not sensor_msgs/msg/LaserScan' in out.stderr
    out = run_cli('--bag', str(tmp_path / 'nothing'))
    assert out.returncode == 2 and 'not a readable rosbag2 recording' in out.stderr


# A TurtleBot 4-like mounting: base_link -> shell_link (on /tf, republished unchanged, as
# robot_state_publisher does) -> rplidar_link (on /tf_static), turned 90 deg and off-centre.
SHELL_ON_BASE = Rigid2D(0.2, 0.0, 0.0)
LASER_ON_SHELL = Rigid2D(0.1, -0.1, math.pi / 2)
LASER_ON_BASE = SHELL_ON_BASE * LASER_ON_SHELL


def transform(parent: str, child: str, pose: Rigid2D, z: float, sec: int, upside_down=False):
    """`pose` on `parent` as a tf message; upside down: rolled by pi (Rz(yaw) Rx(pi))."""
    m = TYPES.types
    c, s = math.cos(pose.yaw / 2), math.sin(pose.yaw / 2)
    x, y, z_rotation, w = (c, s, 0.0, 0.0) if upside_down else (0.0, 0.0, s, c)
    return m['geometry_msgs/msg/TransformStamped'](
        header=m['std_msgs/msg/Header'](stamp=m['builtin_interfaces/msg/Time'](sec=sec, nanosec=0), frame_id=parent),
        child_frame_id=child, transform=m['geometry_msgs/msg/Transform'](
            translation=m['geometry_msgs/msg/Vector3'](x=pose.x, y=pose.y, z=z),
            rotation=m['geometry_msgs/msg/Quaternion'](x=x, y=y, z=z_rotation, w=w)))


def write_mounted_bag(path, office_map, with_tf=True, upside_down=False):
    """Scans taken by the mounted laser with the base at POSES; /tf also carries odom ->
    base_link, which moves (not a mounting). An upside-down laser's beams run clockwise:
    its 270-degree scan is the upright one's ranges in reverse order."""
    rng = np.random.default_rng(5)
    tf_type = 'tf2_msgs/msg/TFMessage'
    with Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        scans = writer.add_connection('/scan', 'sensor_msgs/msg/LaserScan', typestore=TYPES)
        if with_tf:
            tf_static = writer.add_connection('/tf_static', tf_type, typestore=TYPES)
            tf = writer.add_connection('/tf', tf_type, typestore=TYPES)
            writer.write(tf_static, 99 * 10**9, TYPES.serialize_cdr(TYPES.types[tf_type](transforms=[
                transform('shell_link', 'rplidar_link', LASER_ON_SHELL, 0.05, 99, upside_down)]), tf_type))
        for i, base in enumerate(POSES):
            if with_tf:
                moving = [transform('odom', 'base_link', base, 0.0, 100 + i),
                          transform('base_link', 'shell_link', SHELL_ON_BASE, 0.1, 100 + i)]
                message = TYPES.types[tf_type](transforms=moving)
                writer.write(tf, (100 + i) * 10**9, TYPES.serialize_cdr(message, tf_type))
            scan = simulate_scan(office_map, base * LASER_ON_BASE,
                                 LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.0), rng=rng)
            if upside_down:
                scan = replace(scan, ranges=scan.ranges[::-1])
            writer.write(scans, (100 + i) * 10**9 + 5,
                         TYPES.serialize_cdr(laser_scan(scan, 100 + i, 'rplidar_link'), 'sensor_msgs/msg/LaserScan'))


def assert_base_poses(rows, poses=POSES):
    for row, base in zip(rows, poses, strict=True):
        assert row['outcome'] == 'localized', row
        assert pose_correct(Rigid2D(row['x'], row['y'], row['yaw']), base, max_xy=0.1, max_yaw_deg=2.0), (row, base)


@pytest.mark.process
def test_bag_mounting_from_tf_static_and_fixed_tf_gives_base_poses(tmp_path, office_map):
    write_mounted_bag(tmp_path / 'run', office_map)
    out = run_cli('--bag', str(tmp_path / 'run'))
    assert out.returncode == 0, out.stderr
    rows = [json.loads(line) for line in out.stdout.splitlines()]
    assert_base_poses(rows)
    for row in rows:
        mounting = row['mounting']
        assert (mounting['from'], mounting['frames']) == ('/tf, /tf_static', 'base_link -> shell_link -> rplidar_link')
        assert (mounting['x'], mounting['y'], mounting['yaw']) == pytest.approx(LASER_ON_BASE.as_tuple(), abs=1e-4)
    # another base frame: the laser's mounting on it
    shell = json.loads(run_cli('--bag', str(tmp_path / 'run'), '--base-frame', 'shell_link', '--every', '3',
                               ).stdout.splitlines()[0])['mounting']
    assert (shell['from'], shell['frames']) == ('/tf_static', 'shell_link -> rplidar_link')
    assert (shell['x'], shell['y'], shell['yaw']) == pytest.approx(LASER_ON_SHELL.as_tuple(), abs=1e-4)


@pytest.mark.process
def test_bag_with_the_laser_upside_down_turns_its_scans_upright(tmp_path, office_map):
    write_mounted_bag(tmp_path / 'run', office_map, upside_down=True)
    out = run_cli('--bag', str(tmp_path / 'run'))
    assert out.returncode == 0, out.stderr
    rows = [json.loads(line) for line in out.stdout.splitlines()]
    assert_base_poses(rows)
    assert all(row['mounting']['upside_down'] for row in rows)
    assert (rows[0]['mounting']['x'], rows[0]['mounting']['y'], rows[0]['mounting']['yaw']) == \
        pytest.approx(LASER_ON_BASE.as_tuple(), abs=1e-4)


@pytest.mark.process
def test_bag_without_the_transform_uses_the_mounting_flags_and_says_so(tmp_path, office_map):
    write_mounted_bag(tmp_path / 'run', office_map, with_tf=False)
    flags = ('--laser-x', str(LASER_ON_BASE.x), '--laser-y', str(LASER_ON_BASE.y),
             '--laser-yaw', str(LASER_ON_BASE.yaw))
    out = run_cli('--bag', str(tmp_path / 'run'), *flags)
    assert out.returncode == 0, out.stderr
    rows = [json.loads(line) for line in out.stdout.splitlines()]
    assert_base_poses(rows)
    assert rows[0]['mounting']['from'] == '--laser-x/--laser-y/--laser-yaw'
    assert rows[0]['mounting']['because'] == ('the bag has no mounting of the laser on base_link: '
                                              'no transforms on /tf_static or /tf that stay fixed')
    # a base frame the tf tree does not have: the flags, with the reason
    write_mounted_bag(tmp_path / 'tf', office_map)
    out = run_cli('--bag', str(tmp_path / 'tf'), '--base-frame', 'base_footprint', '--every', '3', *flags)
    row = json.loads(out.stdout.splitlines()[0])
    assert row['mounting']['because'].endswith('no chain of fixed transforms from base_footprint to the sensor frame '
                                               'rplidar_link on /tf_static or /tf (odom -> base_link on /tf move '
                                               'during the recording)'), row['mounting']
    assert_base_poses([row], POSES[:1])
