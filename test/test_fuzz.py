"""Property-based fuzzing (hypothesis) of everything that reads outside input: the map
loader (YAML + image, OccupancyGrid fields), the scan validator and the matchers behind
it, the CLI's line parser, and a goal's fields. Every input gets a result or a clear
error (MapError, ScanError, ValueError with a message) - never another exception, never
a non-finite pose. Seeded (derandomize) so a failure reproduces; the examples are kept
few enough for `make test`."""
import json
import math
import os
import tempfile

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import small_room
from global_loc.core.localizer import Localizer, LocalizerConfig
from global_loc.core.map_io import MapError, from_occupancy_grid, load_map_yaml
from global_loc.core.scan import Scan, ScanError, scan_to_points
from global_loc.core.search_region import SearchRegion
from global_loc.core.transform import Rigid2D
from global_loc.offline.cli import json_line_scans

FUZZ = settings(derandomize=True, database=None, deadline=None, max_examples=60,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

any_float = st.floats(allow_nan=True, allow_infinity=True)
odd_scalar = st.one_of(st.none(), st.booleans(), st.integers(-10 ** 12, 10 ** 12), any_float,
                       st.text(max_size=8), st.lists(st.integers(), max_size=3))


def assert_finite_result(result):
    if result.pose is not None:
        assert all(map(math.isfinite, result.pose.as_tuple())), result
    for h in result.hypotheses:
        assert all(map(math.isfinite, h.pose.as_tuple())), result
    assert math.isfinite(result.confidence) and 0.0 <= result.confidence <= 1.0, result
    assert not (result.success and result.confidence <= 0), result


# ---- map loader: YAML and image ------------------------------------------------------------------
yaml_values = st.fixed_dictionaries({}, optional={
    'image': st.one_of(st.just('map.pgm'), st.just('map.png'), st.just('missing.pgm'), st.just('.'), odd_scalar),
    'resolution': st.one_of(st.floats(0.001, 1.0), odd_scalar),
    'origin': st.one_of(st.lists(st.one_of(st.floats(-100, 100), any_float), min_size=0, max_size=4), odd_scalar),
    'negate': st.one_of(st.sampled_from([0, 1]), odd_scalar),
    'occupied_thresh': st.one_of(st.floats(0, 1), odd_scalar),
    'free_thresh': st.one_of(st.floats(0, 1), odd_scalar),
    'mode': st.one_of(st.sampled_from(['trinary', 'scale', 'raw']), odd_scalar),
})
images = st.one_of(
    st.tuples(st.integers(1, 40), st.integers(1, 40), st.sampled_from([np.uint8, np.uint16]), st.integers(1, 4)),
    st.binary(max_size=64))


@FUZZ
@given(doc=yaml_values, image=images, raw_yaml=st.one_of(st.none(), st.binary(max_size=80)))
def test_map_yaml_and_image_load_or_give_a_map_error(doc, image, raw_yaml):
    with tempfile.TemporaryDirectory() as d:
        for name in ('map.pgm', 'map.png'):
            path = os.path.join(d, name)
            if isinstance(image, bytes):
                with open(path, 'wb') as f:
                    f.write(image)
            else:
                h, w, dtype, channels = image
                pixels = np.random.default_rng(h * w).integers(0, np.iinfo(dtype).max, (h, w, channels)).astype(dtype)
                if channels == 2:
                    pixels = pixels[:, :, 0]
                cv2.imwrite(path, pixels if name.endswith('png') or channels in (1, 2, 3) else pixels[:, :, :3])
        yml = os.path.join(d, 'map.yaml')
        with open(yml, 'wb') as f:
            f.write(raw_yaml if raw_yaml is not None else json.dumps(doc).encode())
        try:
            m = load_map_yaml(yml)
        except MapError as e:
            assert str(e)
            return
        assert m.width > 0 and m.height > 0 and math.isfinite(m.resolution) and m.resolution > 0
        assert all(map(math.isfinite, m.origin.as_tuple()))


@FUZZ
@given(width=odd_scalar | st.integers(-3, 30), height=odd_scalar | st.integers(-3, 30),
       resolution=odd_scalar | st.floats(0.01, 1), origin=st.one_of(st.lists(any_float, max_size=4), odd_scalar),
       data=st.one_of(st.lists(st.integers(-200, 200), max_size=900), odd_scalar))
def test_occupancy_grid_fields_give_a_map_or_a_map_error(width, height, resolution, origin, data):
    try:
        m = from_occupancy_grid(width, height, resolution, origin, data)
    except MapError as e:
        assert str(e)
        return
    assert all(map(math.isfinite, m.origin.as_tuple())) and m.occupancy.shape == (m.height, m.width)


# ---- scans: the validator and the matchers behind it ---------------------------------------------
_LOCALIZER = {}
LOCALIZED_SCANS = []


def room_localizer():
    if not _LOCALIZER:
        _LOCALIZER['loc'] = Localizer(small_room(), LocalizerConfig(max_search_s=2.0))
    return _LOCALIZER['loc']


special = st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -1.0, 1e308, -0.0])
ranges = st.lists(st.one_of(*[st.floats(0.05, 6)] * 7, special), max_size=400)


def mostly(valid, odd=special):
    """Usually a plausible value, sometimes an odd one: enough scans get to the matchers."""
    return st.one_of(*[valid] * 7, odd)


@settings(FUZZ, max_examples=120)
@given(angle_min=mostly(st.floats(-4, 4)), angle_increment=mostly(st.floats(0.002, 0.05) | st.floats(-0.05, -0.002)),
       range_min=mostly(st.floats(0, 0.5)), range_max=mostly(st.floats(1, 30)),
       values=ranges, method=st.sampled_from(['bnb', 'template_ccoeff', 'features_orb']))
def test_any_scan_gives_a_result_or_a_scan_error(angle_min, angle_increment, range_min, range_max, values, method):
    scan = Scan(angle_min, angle_increment, range_min, range_max, np.array(values, dtype=float))
    try:
        scan_to_points(scan)
        result = room_localizer().localize(scan, method)
    except ScanError as e:
        assert str(e)
        return
    LOCALIZED_SCANS.append(result.outcome)
    assert_finite_result(result)


def test_the_scan_fuzz_reached_the_matchers():
    """Runs after the fuzz above (file order): it is no test if every scan was refused."""
    assert len(LOCALIZED_SCANS) >= 5, LOCALIZED_SCANS


# ---- the CLI's line parser ----------------------------------------------------------------------
json_scans = st.fixed_dictionaries({'angle_min': any_float | odd_scalar, 'angle_increment': any_float | odd_scalar,
                                    'range_min': any_float | odd_scalar, 'range_max': any_float | odd_scalar,
                                    'ranges': st.lists(any_float | st.none(), max_size=30) | odd_scalar},
                                   optional={'truth': st.dictionaries(st.sampled_from(['x', 'y', 'yaw', 'z']),
                                                                      odd_scalar) | odd_scalar})


def _json_bytes(obj) -> bytes:
    return json.dumps(obj, allow_nan=True).encode()


@FUZZ
@given(lines=st.lists(st.one_of(st.binary(max_size=60), json_scans.map(_json_bytes),
                                st.recursive(odd_scalar, lambda c: st.lists(c, max_size=3)).map(_json_bytes)),
                      max_size=6))
def test_cli_lines_each_give_a_scan_or_a_scan_error(lines):
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, 'scans.jsonl')
        with open(path, 'wb') as f:
            f.write(b'\n'.join(line.replace(b'\n', b' ') for line in lines))
        out = list(json_line_scans(path))
    assert len(out) <= len(lines)
    for where, scan, truth in out:
        assert 'line' in where
        assert isinstance(scan, (Scan, ScanError))
        assert truth is None or all(map(math.isfinite, truth.as_tuple()))


# ---- a goal's fields ------------------------------------------------------------------------------
@FUZZ
@given(method=st.one_of(st.sampled_from(['bnb', 'template_ccoeff', 'features', '']), st.text(max_size=12)),
       angle_step=any_float, center=st.tuples(any_float, any_float, any_float),
       radius=any_float, yaw_tolerance=any_float)
def test_goal_fields_give_a_result_or_a_clear_error(method, angle_step, center, radius, yaw_tolerance):
    """The fields the server reads from a goal, through the same calls it makes."""
    loc = room_localizer()
    scan = Scan(-2.0, 0.01, 0.05, 8.0, 1.0 + np.abs(np.sin(np.arange(400) * 0.05)))
    try:
        region = SearchRegion(Rigid2D(*center), radius, yaw_tolerance)
        result = loc.localize(scan, method or 'bnb', angle_step or None, region=region)
    except ValueError as e:      # MethodError, a bad angle step, a bad region
        assert str(e)
        return
    assert_finite_result(result)
    if region.bounded:     # searched wider when tighter than the search's resolution; answered inside
        assert result.region.radius_m >= region.radius_m and result.region.yaw_tolerance >= region.yaw_tolerance
        assert all(region.contains(h.pose) for h in result.hypotheses)


@pytest.mark.parametrize('step', [-1.0, math.nan, math.inf, 181.0])   # 0: the default step
def test_goal_angle_step_out_of_range_is_a_value_error(step):
    with pytest.raises(ValueError, match='angle step'):
        room_localizer().localize(Scan(-2.0, 0.01, 0.05, 8.0, np.full(400, 2.0)), 'template_ccoeff', step)
