"""`python -m global_loc localize --bag`: rosbag2 recordings of both storage kinds, written
here with the rosbags library from simulated scans, localized without ROS; recordings
without the topic, or with another type on it, are clear errors."""
import json
import subprocess
import sys

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from conftest import OFFICE_YAML
from global_loc.core.transform import Rigid2D, pose_correct
from global_loc.sim.raycast import simulate_scan

POSES = [Rigid2D(3.0, 4.0, 0.7), Rigid2D(12.0, 8.0, -2.0), Rigid2D(20.0, 12.5, 2.5)]
TYPES = get_typestore(Stores.ROS2_JAZZY)


def laser_scan(scan, sec: int):
    m = TYPES.types
    header = m['std_msgs/msg/Header'](stamp=m['builtin_interfaces/msg/Time'](sec=sec, nanosec=500), frame_id='laser')
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
            scan = simulate_scan(office_map, pose, 270.0, 541, 20.0, noise_std=0.01, rng=rng)
            msg = laser_scan(scan, 100 + i) if msgtype.endswith('LaserScan') else TYPES.types[msgtype](data='x')
            writer.write(conn, (100 + i) * 10**9, TYPES.serialize_cdr(msg, msgtype))
            writer.write(other, (100 + i) * 10**9 + 1, TYPES.serialize_cdr(TYPES.types['std_msgs/msg/String'](
                data='noise'), 'std_msgs/msg/String'))


def run_cli(*args):
    return subprocess.run([sys.executable, '-m', 'global_loc', 'localize', '--map', OFFICE_YAML, *args],
                          capture_output=True, text=True, timeout=300)


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
