"""Helpers shared by the tests: where the data is, pose assertions, the client and a scan
publisher for the ROS tests; the small synthetic maps (global_loc.sim.synthetic_maps)
are re-exported for them."""
import json
import os
import sys

import pytest

from global_loc.core.map_io import load_map_yaml
from global_loc.core.transform import CORRECT_XY_M, CORRECT_YAW_DEG, Rigid2D, pose_correct, pose_error
from global_loc.ros.processes import Process, run_client
from global_loc.sim.synthetic_maps import (  # noqa: F401
    aisles,
    aisles_with_a_box,
    grid_map,
    small_room,
    symmetric_room,
    twin_rooms,
    walled,
)

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TEST_DIR = os.path.join(REPO_ROOT, 'test')
SHARED_DATA = os.path.normpath(os.path.join(REPO_ROOT, '..', 'shared', 'data'))
OFFICE_YAML = os.path.join(REPO_ROOT, 'maps', 'office.yaml')


def shared_path(*parts) -> str:
    """A file under ../shared/data, or skip the test saying what is missing."""
    path = os.path.join(SHARED_DATA, *parts)
    if not os.path.exists(path):
        pytest.skip(f'shared test data not present: {path} (the checkout needs ../shared beside it)')
    return path


@pytest.fixture(scope='session')
def office_map():
    return load_map_yaml(OFFICE_YAML)


def assert_pose_near(estimate: Rigid2D, truth: Rigid2D, max_xy: float = CORRECT_XY_M,
                     max_yaw_deg: float = CORRECT_YAW_DEG) -> None:
    """`estimate` is within max_xy metres and max_yaw_deg degrees of `truth` (by default
    the thesis's success criterion)."""
    assert estimate is not None, f'no pose (truth {truth})'
    d, a = pose_error(estimate, truth)
    assert pose_correct(estimate, truth, max_xy, max_yaw_deg), \
        f'estimate {estimate} is {d:.3f} m, {a:.1f} deg from the truth {truth}'


def any_pose_near(poses, truth: Rigid2D, max_xy: float = CORRECT_XY_M, max_yaw_deg: float = CORRECT_YAW_DEG) -> bool:
    return any(pose_correct(p, truth, max_xy, max_yaw_deg) for p in poses)


# ---- ROS processes -----------------------------------------------------------------------
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


