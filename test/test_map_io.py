"""Map loading: nav2 YAML + image semantics, OccupancyGrid arrays, and clear errors."""
import math
import os

import numpy as np
import pytest

from conftest import shared_path
from global_loc.core.map_io import MapError, from_occupancy_grid, load_map_yaml, save_map_yaml
from global_loc.core.transform import Rigid2D

# From shared/data/README.md: rows x cols and resolution.
SHARED_MAPS = [('willow-2010-02-18-0.10.yaml', (608, 566), 0.10),
               ('building_31.yaml', (648, 693), 0.05),
               ('tb3_sandbox.yaml', (384, 384), 0.05),
               ('depot.yaml', (307, 604), 0.05),
               ('testmap.yaml', (10, 10), 0.1)]


@pytest.mark.parametrize('name, shape, resolution', SHARED_MAPS)
def test_shared_maps_load_with_their_size_and_resolution(name, shape, resolution):
    m = load_map_yaml(shared_path('maps', name))
    assert m.occupancy.shape == shape
    assert m.resolution == pytest.approx(resolution)
    assert m.occupied.any() and m.free.any()
    assert set(np.unique(m.occupancy)) <= set(range(-1, 101))


def test_testmap_origin_yaw_is_used_in_pixel_to_world():
    m = load_map_yaml(shared_path('maps', 'testmap.yaml'))
    assert m.origin.yaw == pytest.approx(1.0)
    # The lower-left pixel's centre is half a cell along the rotated axes from the origin.
    xy = m.frame.pixel_to_world([[0, m.height - 1]])[0]
    half = 0.5 * m.resolution
    expected = (m.origin.x + half * (math.cos(1.0) - math.sin(1.0)),
                m.origin.y + half * (math.sin(1.0) + math.cos(1.0)))
    assert xy == pytest.approx(expected)
    assert m.frame.world_to_pixel([xy])[0] == pytest.approx([0, m.height - 1])


def test_testmap_png_and_pgm_give_the_same_grid(tmp_path):
    import yaml
    src = shared_path('maps', 'testmap.yaml')
    doc = yaml.safe_load(open(src))
    doc['image'] = os.path.join(os.path.dirname(src), 'testmap.png')   # absolute image path
    (tmp_path / 'png.yaml').write_text(yaml.safe_dump(doc))
    assert np.array_equal(load_map_yaml(src).occupancy, load_map_yaml(tmp_path / 'png.yaml').occupancy)


def test_rgb_png_building_map_is_averaged_to_grey():
    m = load_map_yaml(shared_path('maps', 'building_31.yaml'))
    assert m.occupancy.ndim == 2


def test_save_and_load_round_trip_keeps_occupied_free_unknown(tmp_path, office_map):
    save_map_yaml(office_map, tmp_path / 'copy.yaml')
    again = load_map_yaml(tmp_path / 'copy.yaml')
    assert np.array_equal(again.occupancy, office_map.occupancy)
    assert again.origin == office_map.origin
    assert (office_map.occupancy == -1).any()   # the office has unknown outside


def test_occupancy_grid_array_rows_start_at_the_bottom():
    data = np.zeros((3, 4), dtype=int)
    data[0, 1] = 100          # bottom row in OccupancyGrid order
    data[2, 3] = -1
    m = from_occupancy_grid(4, 3, 0.5, (1.0, 2.0, 0.0), data.ravel())
    assert m.occupancy[2, 1] == 100 and m.occupancy[0, 3] == -1
    assert m.frame.pixel_to_world([[1, 2]])[0] == pytest.approx([1.0 + 0.75, 2.0 + 0.25])


@pytest.mark.parametrize('args, fragment', [
    ((0, 3, 0.1, (0, 0, 0), []), 'empty grid'),
    ((2, 2, 0.0, (0, 0, 0), [0] * 4), 'resolution'),
    ((2, 2, 0.1, (0, 0, 0), [0] * 3), 'expected 2 x 2'),
    ((2, 2, 0.1, (0, 0, 0), [0, 0, 0, 101]), '-1..100'),
])
def test_bad_occupancy_grid_arrays_raise_map_error(args, fragment):
    with pytest.raises(MapError, match=fragment):
        from_occupancy_grid(*args)


GOOD_YAML = ('image: {image}\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\noccupied_thresh: 0.65\n'
             'free_thresh: 0.196\n')


@pytest.mark.parametrize('text, fragment', [
    ('image: [unclosed\n', 'not valid YAML'),
    ('- just\n- a list\n', 'expected a mapping'),
    (GOOD_YAML.replace('resolution: 0.05\n', ''), "missing key 'resolution'"),
    (GOOD_YAML.replace('0.05', '0'), 'resolution must be a positive'),
    (GOOD_YAML.replace('0.05', 'fast'), 'bad value'),
    (GOOD_YAML.replace('occupied_thresh: 0.65', 'occupied_thresh: 0.1'), 'free_thresh < occupied_thresh'),
    (GOOD_YAML.replace('[0.0, 0.0, 0.0]', '[0.0, 0.0]'), 'origin must be'),
    (GOOD_YAML + 'mode: fancy\n', 'mode must be'),
    (GOOD_YAML.replace('{image}', 'nothere.pgm'), 'not found'),
    (GOOD_YAML.replace('{image}', 'garbage.pgm'), 'could not be read'),
])
def test_malformed_map_yaml_raises_map_error_naming_the_file(tmp_path, office_map, text, fragment):
    save_map_yaml(office_map, tmp_path / 'ok.yaml')
    (tmp_path / 'garbage.pgm').write_bytes(b'this is not an image')
    path = tmp_path / 'map.yaml'
    path.write_text(text.replace('{image}', 'ok.pgm'))
    with pytest.raises(MapError, match=fragment) as err:
        load_map_yaml(path)
    assert str(path) in str(err.value)


def test_missing_yaml_file_raises_map_error(tmp_path):
    with pytest.raises(MapError, match='not found'):
        load_map_yaml(tmp_path / 'nope.yaml')


def test_negate_and_scale_modes(tmp_path):
    import cv2
    img = np.array([[0, 128, 255]], dtype=np.uint8)
    cv2.imwrite(str(tmp_path / 'tiny.pgm'), img)
    base = GOOD_YAML.format(image='tiny.pgm')
    (tmp_path / 'trinary.yaml').write_text(base)
    (tmp_path / 'negate.yaml').write_text(base.replace('negate: 0', 'negate: 1'))
    (tmp_path / 'scale.yaml').write_text(base + 'mode: scale\n')
    (tmp_path / 'raw.yaml').write_text(base + 'mode: raw\n')
    assert list(load_map_yaml(tmp_path / 'trinary.yaml').occupancy[0]) == [100, -1, 0]
    assert list(load_map_yaml(tmp_path / 'negate.yaml').occupancy[0]) == [0, -1, 100]
    scale = load_map_yaml(tmp_path / 'scale.yaml').occupancy[0]
    assert scale[0] == 100 and scale[2] == 0 and 0 < scale[1] < 100
    assert list(load_map_yaml(tmp_path / 'raw.yaml').occupancy[0]) == [0, -1, -1]


def test_world_pixel_round_trip_with_rotated_origin():
    m = from_occupancy_grid(50, 40, 0.1, Rigid2D(3.0, -2.0, 2.2), [0] * 2000)
    pts = np.array([[0.3, 7.0], [12.5, 3.3], [-4.0, -1.0]])
    assert m.frame.pixel_to_world(m.frame.world_to_pixel(pts)) == pytest.approx(pts)
