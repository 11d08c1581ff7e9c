"""Scans, their validation, and local maps from scans (core.scan, core.local_grid)."""
import math

import numpy as np
import pytest

from global_loc.core.local_grid import build_local_grid, close_obstacles, crop_to_obstacles, rasterize
from global_loc.core.scan import Scan, ScanError, ScanPoints, scan_to_points


def make_scan(ranges, range_min=0.1, range_max=10.0):
    return Scan(-math.pi / 2, math.pi / 2, range_min, range_max, np.array(ranges, dtype=float))


def test_invalid_readings_are_dropped_and_counted():
    pts = scan_to_points(make_scan([1.0, np.nan, np.inf, 0.05, 10.0, -np.inf, 2.0]))
    assert len(pts.points) == 2
    assert pts.dropped == {'nan': 1, 'inf': 2, 'below_range_min': 1, 'at_or_above_range_max': 1}
    # +inf and a reading at range_max saw nothing (free space along the beam); NaN, -inf
    # ("too close", REP 117) and a reading below range_min say nothing about it.
    angles = -math.pi / 2 + math.pi / 2 * np.array([2, 4])
    assert pts.no_return_angles == pytest.approx(angles)


def test_points_are_in_the_laser_frame_counter_clockwise_from_angle_min():
    pts = scan_to_points(make_scan([1.0, 2.0, 3.0])).points
    assert pts == pytest.approx(np.array([[0.0, -1.0], [2.0, 0.0], [0.0, 3.0]]), abs=1e-12)


@pytest.mark.parametrize('ranges', [[], [np.nan, np.inf, -np.inf], [0.0, 0.01], [50.0]])
def test_empty_or_all_invalid_scan_is_a_clear_error(ranges):
    with pytest.raises(ScanError, match='no (valid )?reading'):
        scan_to_points(make_scan(ranges))


@pytest.mark.parametrize('field, value, fragment', [
    ('angle_increment', 0.0, 'angle_increment is 0'),
    ('range_max', float('nan'), 'not finite'),
    ('range_min', 20.0, 'range_min < range_max'),
])
def test_malformed_scan_fields_are_a_clear_error(field, value, fragment):
    scan = make_scan([1.0, 2.0, 3.0])
    setattr(scan, field, value)
    with pytest.raises(ScanError, match=fragment):
        scan_to_points(scan)


def test_scan_from_json_with_null_ranges_and_missing_fields():
    s = Scan.from_dict({'angle_min': 0, 'angle_increment': 0.1, 'range_min': 0, 'range_max': 5,
                        'ranges': [1.0, None, 2.0]})
    assert np.isnan(s.ranges[1])
    with pytest.raises(ScanError, match='missing field'):
        Scan.from_dict({'angle_min': 0})
    with pytest.raises(ScanError, match='non-numeric'):
        Scan.from_dict({'angle_min': 'a', 'angle_increment': 0.1, 'range_min': 0, 'range_max': 5, 'ranges': []})


def test_rasterize_puts_the_laser_at_the_centre_with_side_twice_the_farthest_point():
    pts = ScanPoints(np.array([[1.0, 0.0], [0.0, 0.5]]), range_max=2.0, num_beams=2)
    grid = rasterize(pts, 0.1)
    assert grid.image.shape == (23, 23)   # 1 m (10 cells) and one cell each side of the laser
    assert grid.laser_px == (11.0, 11.0)
    assert grid.image[11, 21] == 255      # 1 m ahead: 10 columns right
    assert grid.image[6, 11] == 255       # 0.5 m left (+y): 5 rows up
    assert grid.image.sum() == 2 * 255
    # a huge range_max (fuzzed: 1e308) does not size the image; max_range caps it
    assert rasterize(ScanPoints(pts.points, range_max=1e308, num_beams=2), 0.1).image.shape == (23, 23)
    assert rasterize(pts, 0.1, max_range=0.6).image.sum() == 255


def test_crop_remembers_offsets_so_the_laser_pixel_moves():
    pts = ScanPoints(np.array([[1.0, 0.0], [1.0, 0.5]]), range_max=2.0, num_beams=2)
    crop = crop_to_obstacles(rasterize(pts, 0.1))     # half side: ceil(1.118 / 0.1) + 1 = 13 cells
    assert crop.image.shape == (6, 1)
    assert crop.crop_offset == (23, 8)
    assert crop.laser_px == (13.0 - 23, 13.0 - 8)


def test_closing_joins_a_dotted_wall_into_a_line_and_zero_kernel_is_off():
    # Returns every second cell along a wall, as a far wall gives at grazing angles.
    ys = np.arange(-1.0, 1.0, 0.2)
    pts = ScanPoints(np.stack([np.full_like(ys, 1.5), ys], axis=1), range_max=2.0, num_beams=len(ys))
    raw = build_local_grid(pts, 0.1, closing_kernel=0)
    joined = build_local_grid(pts, 0.1, closing_kernel=3)
    column = raw.image[:, int(raw.laser_px[0] + 15)]
    assert (column[column.nonzero()[0].min():column.nonzero()[0].max() + 1] == 0).any()   # gaps
    column = joined.image[:, int(joined.laser_px[0] + 15)]
    assert (column[column.nonzero()[0].min():column.nonzero()[0].max() + 1] == 255).all()  # a line
    assert close_obstacles(raw, 0).image is raw.image


def test_the_cli_names_the_closing_by_what_it_does_and_keeps_the_thesiss_name():
    from global_loc.offline.cli import build_parser
    for flag in ('--closing-kernel', '--opening-kernel'):     # the ROS parameter is opening_kernel
        args = build_parser().parse_args(['localize', '--scans', 'scans.jsonl', flag, '5'])
        assert args.closing_kernel == 5
