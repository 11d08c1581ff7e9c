"""Helpers shared by the tests: where the data is, pose assertions, the client and a scan
publisher for the ROS tests, and small synthetic maps built for one property each (no
symmetry, four-fold symmetry, twin aisles, twin rooms)."""
import json
import os
import sys

import numpy as np
import pytest

from global_loc.core.map_io import from_occupancy_grid, load_map_yaml
from global_loc.core.transform import CORRECT_XY_M, CORRECT_YAW_DEG, Rigid2D, pose_correct, pose_error
from global_loc.ros.processes import Process, run_client

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


def grid_map(grid, resolution: float = 0.05):
    """An OccupancyMap from rows of cell values, row 0 at y = 0 (OccupancyGrid order)."""
    grid = np.asarray(grid)
    return from_occupancy_grid(grid.shape[1], grid.shape[0], resolution, (0.0, 0.0, 0.0), grid.ravel())


def walled(rows: int, cols: int) -> np.ndarray:
    """A rows x cols grid of free cells inside a one-cell wall."""
    grid = np.zeros((rows, cols), dtype=int)
    grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = 100
    return grid


def small_room():
    """A 4 x 3 m room at 5 cm with an L-shaped desk and a pillar: no symmetry."""
    grid = walled(60, 80)
    grid[10:14, 20:45] = 100
    grid[10:30, 41:45] = 100
    grid[40:44, 60:64] = 100
    return grid_map(grid)


def symmetric_room():
    """A 6 x 6 m square room with four identical pillars placed four-fold symmetrically."""
    grid = walled(120, 120)
    for r, c in ((30, 30), (30, 86), (86, 30), (86, 86)):
        grid[r:r + 4, c:c + 4] = 100
    return grid_map(grid)


def aisles():
    """A 12 x 6 m store at 5 cm: three identical 8 m shelves make two identical aisles, and
    the whole is symmetric under a half turn about its centre (6, 3)."""
    grid = walled(120, 240)
    for y in (1.5, 3.0, 4.5):
        grid[round(y / 0.05) - 3:round(y / 0.05) + 3, 40:200] = 100
    return grid_map(grid)


def twin_rooms(door_b_closed: bool, chair_in: str):
    """Two identical 4 x 3.5 m rooms (A left, B right) off one long featureless corridor,
    each with a door onto it; B's door may be closed, and a 0.3 m chair may stand in one."""
    res = 0.05
    w, h = int(24 / res), int(5.5 / res)
    grid = np.zeros((h, w), dtype=int)

    def occ(x0, x1, y0, y1, value=100):      # a box in metres (y up, row 0 at y = 0)
        grid[int(round(y0 / res)):int(round(y1 / res)), int(round(x0 / res)):int(round(x1 / res))] = value

    occ(0, 24, 0, 0.05), occ(0, 24, 5.45, 5.5), occ(0, 0.05, 0, 5.5), occ(23.95, 24, 0, 5.5)
    occ(0, 24, 2.0, 2.05)                                   # the rooms' wall onto the corridor
    for x in (2, 6, 16, 20):
        occ(x, x + 0.05, 2.0, 5.5)
    occ(3.6, 4.4, 2.0, 2.05, 0)                            # A's door
    if not door_b_closed:
        occ(17.6, 18.4, 2.0, 2.05, 0)                      # B's door
    cx = {'A': 5.0, 'B': 19.0}[chair_in]
    occ(cx, cx + 0.3, 4.2, 4.5)
    return grid_map(grid, res)


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


