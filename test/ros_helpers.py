"""Helpers for the tests that run ROS processes: the client's --json result and a scan
publisher. Only ROS tests import this (conftest.py must import without rclpy: the
compatibility run has no ROS)."""
import json
import os
import sys

from conftest import TEST_DIR
from global_loc.core.transform import Rigid2D
from global_loc.testing.processes import Process, run_client

TRUTH = Rigid2D(3.0, 4.0, 0.7)     # an office place every matcher but features gets right (test_matchers)


def localize(env, *args, timeout=120.0):
    """The client with --json: (exit code, its result as a dict)."""
    out = run_client(env, '--json', *args, timeout=timeout)
    assert out.stdout.strip(), out.stderr
    return out.returncode, json.loads(out.stdout)


def assert_localizes(env, truth: Rigid2D, *args) -> dict:
    """The client (with `args`) localizes confidently, within the thesis criterion of `truth`."""
    from conftest import assert_pose_near
    code, result = localize(env, '--timeout', '10', *args)
    assert code == 0, result
    assert_pose_near(pose_of(result), truth)
    return result


def pose_of(result: dict) -> Rigid2D:
    return Rigid2D(result['pose']['x'], result['pose']['y'], result['pose']['yaw'])


def start_scan_publisher(env, log_path, map_yaml, pose: Rigid2D, rate=5.0, mode='upright') -> Process:
    """test/scan_publisher.py: scans ray-cast at `pose` (numpy, not the simulator); `mode`
    upside_down or mirrored: see its docstring."""
    return Process([sys.executable, os.path.join(TEST_DIR, 'scan_publisher.py'), str(map_yaml),
                    *map(str, pose.as_tuple()), str(rate), mode], env, log_path)


class ApiLocalizer:
    """global_loc.ros.api.GlobalLocalizer in the test process, on the env's domain (an
    rclpy context of its own); `.api` is the localizer."""

    def __init__(self, env, **kwargs):
        import rclpy

        from global_loc.ros.api import GlobalLocalizer
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=int(env['ROS_DOMAIN_ID']))
        self.api = GlobalLocalizer('test_localizer', context=self.context, **kwargs)

    def close(self) -> None:
        self.api.destroy_node()
        self.context.try_shutdown()
