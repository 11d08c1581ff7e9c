"""A test helper process: several sensors at a known pose on a map, some of them broken.

usage: python sensor_publisher.py MAP_YAML X Y YAW SENSORS_JSON
SENSORS_JSON: a list of {"topic", "kind"} objects:
  kind "scan": a LaserScan ray-cast at the pose * its mounting ("mount": [x y z roll pitch
    yaw], "fov", "beams", "range_max", "frame", "stamp_offset_s": added to its stamps - a
    clock far apart; "silent_if": a path - while that file exists it publishes nothing);
  kind "cloud_no_xyz": a PointCloud2 whose fields are named a/b/c;
  kind "cloud_bad_point_step": point_step 12 for data laid out 32 bytes a point;
  kind "cloud_bad_row_step": row_step one point longer than the data has.
Everything at 5 Hz.
"""
import json
import os
import sys

import numpy as np
import rclpy
from rclpy.duration import Duration
from rclpy.time import Time
from sensor_msgs.msg import LaserScan, PointCloud2, PointField

from global_loc.core.map_io import load_map_yaml
from global_loc.core.mount3d import Mount3D
from global_loc.core.transform import Rigid2D
from global_loc.ros.cloud import cloud_to_msg
from global_loc.ros.convert import scan_to_msg
from global_loc.ros.node_main import run_node
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import simulate_scan


def broken_cloud(kind: str, stamp) -> PointCloud2:
    msg = cloud_to_msg(np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.5], [2.0, 2.0, 1.0]]), 'lidar', stamp)
    if kind == 'cloud_no_xyz':
        msg.fields = [PointField(name=n, offset=f.offset, datatype=f.datatype, count=f.count)
                      for n, f in zip('abcd', msg.fields, strict=True)]
    elif kind == 'cloud_bad_point_step':
        msg.point_step = 12
    elif kind == 'cloud_bad_row_step':
        msg.row_step += msg.point_step
    return msg


def main():
    map_yaml, x, y, yaw = sys.argv[1], *map(float, sys.argv[2:5])
    sensors = json.loads(sys.argv[5])
    occupancy_map, truth = load_map_yaml(map_yaml), Rigid2D(x, y, yaw)

    def make_node():      # run_node (the package's one way a node runs) inits, spins and stops
        node = rclpy.create_node('test_sensor_publisher')
        rng = np.random.default_rng(0)
        pubs = {s['topic']: node.create_publisher(LaserScan if s['kind'] == 'scan' else PointCloud2, s['topic'], 5)
                for s in sensors}

        def tick():
            now = node.get_clock().now()
            for s in sensors:
                if 'silent_if' in s and os.path.exists(s['silent_if']):
                    continue
                if s['kind'] != 'scan':
                    pubs[s['topic']].publish(broken_cloud(s['kind'], now.to_msg()))
                    continue
                mount = Mount3D.from_values(s.get('mount', [0.0] * 6))
                laser = LaserConfig(s.get('fov', 270.0), s.get('beams', 541), range_max=s.get('range_max', 20.0),
                                    noise_std=0.01, dropout=0.0)
                scan = simulate_scan(occupancy_map, truth * mount.upright(), laser, rng=rng)
                offset = s.get('stamp_offset_s', 0.0)
                stamp = (now + Duration(seconds=offset) if offset >= 0 else
                         Time(nanoseconds=now.nanoseconds - int(-offset * 1e9))).to_msg()
                pubs[s['topic']].publish(scan_to_msg(scan, s.get('frame', 'laser'), stamp))

        node.create_timer(0.2, tick)
        return node

    sys.exit(run_node(make_node))


if __name__ == '__main__':
    main()
