"""GridFrame, the one owner of cell geometry: points, cells, poses and covariances."""
import math

import numpy as np
import pytest

from global_loc.core.grid_frame import GridFrame
from global_loc.core.transform import Rigid2D

ROTATED = GridFrame(0.1, 50, 40, Rigid2D(3.0, -2.0, 2.2))


def test_pixel_centres_and_the_lower_left_corner():
    frame = GridFrame(0.5, 4, 3, Rigid2D(1.0, 2.0, 0.0))
    # cell (col 1, row 2) is in the bottom row: its centre is 1.5 cells right, 0.5 up from the corner
    assert frame.pixel_to_world([[1, 2]])[0] == pytest.approx([1.0 + 0.75, 2.0 + 0.25])
    assert frame.pixel_to_world([[-0.5, 2.5]])[0] == pytest.approx([1.0, 2.0])     # the corner itself


def test_points_and_poses_round_trip_with_a_rotated_origin():
    pts = np.array([[0.3, 7.0], [12.5, 3.3], [-4.0, -1.0]])
    assert ROTATED.pixel_to_world(ROTATED.world_to_pixel(pts)) == pytest.approx(pts)
    pose = Rigid2D(4.0, 1.0, -0.4)
    back = ROTATED.pixel_pose_to_world(*ROTATED.world_pose_to_pixel(pose))
    assert back.as_tuple() == pytest.approx(pose.as_tuple())
    u, v, yaw = ROTATED.world_pose_to_pixel(pose)
    assert yaw == pytest.approx(-0.4 - 2.2)


def test_cell_of_and_contains():
    frame = GridFrame(0.1, 10, 5)
    cells = frame.cell_of([[0.05, 0.05], [0.99, 0.49], [1.0, 0.0], [-0.01, 0.2]])
    assert cells.tolist() == [[0, 4], [9, 0], [10, 4], [-1, 2]]
    assert frame.contains(cells).tolist() == [True, True, False, False]
    # every point lands in the cell whose centre is nearest, also with a rotated origin
    rng = np.random.default_rng(1)
    pts = ROTATED.pixel_to_world(rng.uniform(0, 30, (200, 2)))
    centres = ROTATED.pixel_to_world(ROTATED.cell_of(pts))
    assert np.all(np.abs(ROTATED.origin.inverse().apply(pts) - ROTATED.origin.inverse().apply(centres)) <= 0.05 + 1e-9)


def test_pixel_steps_point_down_and_the_matrix_agrees_with_pixel_to_grid():
    frame = GridFrame(0.2, 7, 9)
    dx, dy = frame.pixel_steps_to_grid(np.array([1.0]), np.array([1.0]))
    assert (dx[0], dy[0]) == pytest.approx((0.2, -0.2))
    uv = np.array([2.5, 3.0, 1.0])
    assert (frame.pixel_to_grid_matrix() @ uv)[:2] == pytest.approx(frame.pixel_to_grid(uv[:2])[0])


def test_covariance_turns_with_the_origin():
    frame = GridFrame(0.1, 10, 10, Rigid2D(0.0, 0.0, math.pi / 2))
    cov = frame.covariance_to_world(np.diag([4.0, 1.0, 0.5]))
    assert cov == pytest.approx(np.diag([1.0, 4.0, 0.5]))


def test_centred_frame_puts_the_origin_at_the_centre_cell():
    frame = GridFrame.centred(0.05, 10)
    assert (frame.width, frame.height) == (21, 21)
    assert frame.cell_of([[0.0, 0.0]]).tolist() == [[10, 10]]
    assert frame.pixel_to_world([[10, 10]])[0] == pytest.approx([0.0, 0.0])
