"""Pose from a match: composed transforms against the thesis-style expanded formula."""
import math

import numpy as np
import pytest

from global_loc.core.local_grid import LocalGrid, crop_to_obstacles, rasterize
from global_loc.core.map_io import from_occupancy_grid
from global_loc.core.matchers.template import rotate_tight
from global_loc.core.pose import pose_from_match, translation_px
from global_loc.core.scan import ScanPoints
from global_loc.core.transform import Rigid2D, normalize_angle


def expanded_formula(origin, res, map_h, match_uv, alpha_deg, laser_px, rot_center, rot_offset, local_h):
    """Robot pose written out in one line each, eq. 2.18-style: the laser pixel rotated by
    α about the template's rotation centre, shifted onto the match, then pixel -> map."""
    a = math.radians(alpha_deg)
    du, dv = laser_px[0] - rot_center[0], laser_px[1] - rot_center[1]
    u = match_uv[0] + rot_offset[0] + rot_center[0] + math.cos(a) * du + math.sin(a) * dv
    v = match_uv[1] + rot_offset[1] + rot_center[1] - math.sin(a) * du + math.cos(a) * dv
    gx, gy = (u + 0.5) * res, (map_h - v - 0.5) * res
    x = origin.x + math.cos(origin.yaw) * gx - math.sin(origin.yaw) * gy
    y = origin.y + math.sin(origin.yaw) * gx + math.cos(origin.yaw) * gy
    return x, y, normalize_angle(origin.yaw + a)


@pytest.mark.parametrize('origin', [Rigid2D(0, 0, 0), Rigid2D(-3.0, 2.0, 0.0), Rigid2D(1.0, -2.0, 1.0)])
@pytest.mark.parametrize('alpha_deg', [0.0, 35.0, -120.0])
@pytest.mark.parametrize('cropped', [False, True])
def test_pose_from_match_with_crop_and_rotation_matches_the_expanded_formula(origin, alpha_deg, cropped):
    res, map_h = 0.05, 300
    occupancy_map = from_occupancy_grid(400, map_h, res, origin, [0] * (400 * map_h))
    pts = ScanPoints(np.array([[2.0, 1.0], [-1.5, 3.0], [0.5, -2.5]]), range_max=4.0, num_beams=3)
    local = rasterize(pts, res)
    if cropped:
        local = crop_to_obstacles(local)
    templ, local_to_templ = rotate_tight(local.image, alpha_deg)
    match_uv = (123, 77)
    pose = pose_from_match(occupancy_map, local, translation_px(*match_uv) @ local_to_templ)
    # The same numbers through the formula: rotate_tight's affine is a rotation about the
    # image centre followed by a shift, which the formula takes as separate terms.
    center = ((local.width - 1) / 2.0, (local.height - 1) / 2.0)
    a = local_to_templ
    offset = (a[0, 2] - (center[0] - (a[0, 0] * center[0] + a[0, 1] * center[1])),
              a[1, 2] - (center[1] - (a[1, 0] * center[0] + a[1, 1] * center[1])))
    x, y, yaw = expanded_formula(origin, res, map_h, match_uv, alpha_deg, local.laser_px, center, offset, local.height)
    assert (pose.x, pose.y) == pytest.approx((x, y), abs=1e-9)
    assert normalize_angle(pose.yaw - yaw) == pytest.approx(0.0, abs=1e-9)


def test_identity_match_of_an_uncropped_local_map_centred_on_a_map_pixel():
    occupancy_map = from_occupancy_grid(101, 101, 0.1, (0.0, 0.0, 0.0), [0] * 101 * 101)
    local = LocalGrid(np.zeros((21, 21), np.uint8), 0.1, (10.0, 10.0))
    pose = pose_from_match(occupancy_map, local, translation_px(40, 30))
    # laser pixel (10, 10) lands on map pixel (50, 40): centre at x = 5.05, y = (101-40-0.5)*0.1
    assert pose.as_tuple() == pytest.approx((5.05, 6.05, 0.0))


def test_rigid2d_compose_inverse_and_apply_round_trip():
    a, b = Rigid2D(1.0, -2.0, 0.7), Rigid2D(-0.3, 4.0, -2.5)
    ab = a * b
    assert (ab * b.inverse()).as_tuple() == pytest.approx(a.as_tuple())
    assert (a.inverse() * a).as_tuple() == pytest.approx((0, 0, 0), abs=1e-12)
    p = np.array([[1.0, 2.0], [-3.0, 0.5]])
    assert ab.apply(p) == pytest.approx(a.apply(b.apply(p)))
    assert Rigid2D.from_matrix(ab.matrix()).as_tuple() == pytest.approx(ab.as_tuple())


def test_scale_in_a_feature_affine_is_divided_out():
    occupancy_map = from_occupancy_grid(100, 100, 0.1, (0.0, 0.0, 0.0), [0] * 10000)
    local = LocalGrid(np.zeros((21, 21), np.uint8), 0.1, (10.0, 10.0))
    exact = pose_from_match(occupancy_map, local, translation_px(40, 30))
    scaled = np.diag([1.05, 1.05, 1.0]) @ np.eye(3)
    scaled[:2, 2] = (40 - 0.05 * 10, 30 - 0.05 * 10)   # same image of the laser pixel
    assert pose_from_match(occupancy_map, local, scaled).as_tuple() == pytest.approx(exact.as_tuple())
