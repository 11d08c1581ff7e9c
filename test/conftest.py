"""Helpers shared by the tests: where the data is, pose assertions; the small synthetic
maps (global_loc.sim.synthetic_maps) are re-exported for them. No ROS import here: the
compatibility run (scripts/compat.sh) has no ROS, so the ROS tests' helpers live in
ros_helpers.py, and a test file that cannot import ROS is skipped where ROS is absent (one
that cannot import pybullet, where pybullet is absent)."""
import importlib.util
import os
import re

import numpy as np
import pytest

from global_loc.core.map_io import load_map_yaml
from global_loc.core.transform import CORRECT_XY_M, CORRECT_YAW_DEG, Rigid2D, pose_correct, pose_error
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


def seeded_office_scans(count: int):
    """(office map, [(scan, truth)]): the first `count` of a seeded sequence of 20 simulated
    270 deg / 20 m office scans (1 cm noise, 2% dropouts; the seed, length and order fix them)."""
    import numpy as np

    from global_loc.sim.laser import LaserConfig
    from global_loc.sim.raycast import sample_free_poses, simulate_scan
    office = load_map_yaml(OFFICE_YAML)
    rng = np.random.default_rng(0)
    scans = []
    for pose in sample_free_poses(office, 20, rng)[:count]:
        scans.append((simulate_scan(office, pose,
                                    LaserConfig(270, 541, range_max=20.0, noise_std=0.01, dropout=0.02),
                                    rng=rng), pose))
    return office, scans


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


# ---- tests that need ROS or the simulator -----------------------------------------------------
ROS_INSTALLED = importlib.util.find_spec('rclpy') is not None
# The compatibility run (scripts/compat.sh) has no pybullet: a test of the simulator skips there.
PYBULLET_INSTALLED = importlib.util.find_spec('pybullet') is not None
NO_PYBULLET = 'needs pybullet (the simulator), which is not installed (scripts/compat.sh leaves it out)'
needs_pybullet = pytest.mark.skipif(not PYBULLET_INSTALLED, reason=NO_PYBULLET)


def is_ros_module(name: str) -> bool:
    """A module of ROS 2 itself or of an interface package (std_msgs, std_srvs, builtin_interfaces, ...)."""
    top = (name or '').split('.')[0]
    return top in ('rclpy', 'tf2_ros', 'launch', 'launch_ros', 'ament_index_python') or \
        top.endswith(('_msgs', '_srvs', '_interfaces'))


def pytest_configure(config):
    config.addinivalue_line('markers', 'ros: starts ROS processes or imports rclpy (deselect with -m "not ros")')
    config.addinivalue_line('markers', 'process: starts a process (the command line, the benchmark); `make check` '
                                       'deselects these and the ros tests')


@pytest.fixture(autouse=True)
def _no_process_in_the_fast_tier(request, monkeypatch):
    """Under `-m "... not process"` (make check) a test that starts a process unmarked fails
    saying so, so the fast tier stays what it says."""
    if 'not process' not in (request.config.getoption('markexpr') or ''):
        return
    import subprocess

    def refuse(*args, **kwargs):
        raise AssertionError(f'{request.node.nodeid} starts a process ({args[0] if args else kwargs}): '
                             'mark it @pytest.mark.process')
    monkeypatch.setattr(subprocess, 'Popen', refuse)


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    """Without ROS, a test file that fails to import only because a ROS module is missing
    is skipped with that reason; every other import error stays an error."""
    outcome = yield
    report = outcome.get_result()
    if not report.failed or not isinstance(collector, pytest.Module):
        return
    missing = re.search(r"ModuleNotFoundError: No module named '([\w.]+)'", str(report.longrepr))
    reason = None
    if missing and is_ros_module(missing.group(1)) and not ROS_INSTALLED:
        reason = f'needs ROS 2, which is not installed: no module {missing.group(1)}'
    elif missing and missing.group(1) == 'pybullet' and not PYBULLET_INSTALLED:
        reason = NO_PYBULLET
    if reason:
        report.outcome = 'skipped'
        report.longrepr = (str(collector.path), 0, reason)


def brute_force_leaves(matcher, pts, d0, n_angles):
    """The score of every leaf (free cell x angle), scored like the search's leaves."""
    rows, cols = np.nonzero(matcher.map.free)
    return np.concatenate([matcher.bounds(0, cols, rows, np.full(len(cols), a), pts, d0) for a in range(n_angles)])
