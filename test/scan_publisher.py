"""A test helper process: publishes LaserScans ray-cast at a known pose on a map.

usage: python scan_publisher.py MAP_YAML X Y YAW [RATE_HZ [MODE]]
MODE: upright (default); upside_down (what a laser mounted upside down sends: the beams
in the opposite order); mirrored (angle_increment's sign flipped by a broken filter, so it
contradicts angle_min/angle_max).
"""
import sys

import numpy as np
import rclpy
from sensor_msgs.msg import LaserScan

from global_loc.core.map_io import load_map_yaml
from global_loc.core.transform import Rigid2D
from global_loc.ros.convert import scan_to_msg
from global_loc.ros.node_main import run_node
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import simulate_scan


def main():
    map_yaml, x, y, yaw = sys.argv[1], *map(float, sys.argv[2:5])
    rate = float(sys.argv[5]) if len(sys.argv) > 5 else 5.0
    mode = sys.argv[6] if len(sys.argv) > 6 else 'upright'
    occupancy_map = load_map_yaml(map_yaml)
    rng = np.random.default_rng(0)

    def make_node():      # run_node (the package's one way a node runs) inits, spins and stops
        node = rclpy.create_node('test_scan_publisher')
        pub = node.create_publisher(LaserScan, '/scan', 5)

        def tick():
            scan = simulate_scan(occupancy_map, Rigid2D(x, y, yaw),
                                 LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.02), rng=rng)
            if mode == 'upside_down':
                scan.ranges = scan.ranges[::-1]
            msg = scan_to_msg(scan, 'laser', node.get_clock().now().to_msg())
            if mode == 'mirrored':
                msg.angle_increment = -msg.angle_increment
            pub.publish(msg)

        node.create_timer(1.0 / rate, tick)
        return node

    sys.exit(run_node(make_node))


if __name__ == '__main__':
    main()
