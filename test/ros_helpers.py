"""Helpers for the tests that run ROS processes: the client's --json result and a scan
publisher. Only ROS tests import this (conftest.py must import without rclpy: the
compatibility run has no ROS)."""
import json
import os
import sys

from conftest import TEST_DIR
from global_loc.core.transform import Rigid2D
from global_loc.ros.processes import Process, run_client

TRUTH = Rigid2D(3.0, 4.0, 0.7)     # an office place every matcher but features gets right (test_matchers)


def localize(env, *args, timeout=120.0):
    """The client with --json: (exit code, its result as a dict)."""
    out = run_client(env, '--json', *args, timeout=timeout)
    assert out.stdout.strip(), out.stderr
    return out.returncode, json.loads(out.stdout)


def pose_of(result: dict) -> Rigid2D:
    return Rigid2D(result['pose']['x'], result['pose']['y'], result['pose']['yaw'])


def start_scan_publisher(env, log_path, map_yaml, pose: Rigid2D, rate=5.0) -> Process:
    """test/scan_publisher.py: scans ray-cast at `pose` (numpy, not the simulator)."""
    return Process([sys.executable, os.path.join(TEST_DIR, 'scan_publisher.py'), str(map_yaml),
                    *map(str, pose.as_tuple()), str(rate)], env, log_path)
