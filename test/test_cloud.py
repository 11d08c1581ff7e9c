"""The PointCloud2 reader (core.cloud, and its ROS wrapper ros.cloud): x/y/z found by the
PointField layout whatever it is, and every layout that does not fit its data refused
with a CloudError. Test clouds are written point by point with `struct`, independently
of the reader's numpy dtypes."""
import struct

import numpy as np
import pytest

from global_loc.core.cloud import CloudError, CloudField, PackedCloud, cloud_xyz, pack_cloud

CODES = {1: 'b', 2: 'B', 3: 'h', 4: 'H', 5: 'i', 6: 'I', 7: 'f', 8: 'd'}
SIZES = {k: struct.calcsize(v) for k, v in CODES.items()}


def write_cloud(points, fields, point_step, big=False, height=1, row_pad=0, values=None):
    """A PackedCloud whose points (rows of x, y, z) are written field by field with struct;
    fields: (name, offset, datatype); other fields get `values[name]` or 7."""
    points = np.asarray(points, dtype=float)
    width = len(points) // height
    row_step = width * point_step + row_pad
    data = bytearray(height * row_step)
    order = '>' if big else '<'
    for i, p in enumerate(points):
        base = (i // width) * row_step + (i % width) * point_step
        for name, offset, datatype in fields:
            value = p['xyz'.index(name)] if name in 'xyz' else (values or {}).get(name, 7)
            if CODES[datatype] not in 'fd':
                value = int(value)
            struct.pack_into(order + CODES[datatype], data, base + offset, value)
    cloud_fields = tuple(CloudField(n, o, d) for n, o, d in fields)
    return PackedCloud(height, width, cloud_fields, big, point_step, row_step, bytes(data))


POINTS = np.array([[1.0, 2.0, 0.5], [-3.25, 0.125, 1.75], [10.5, -4.0, -0.25], [0.0, 0.0, 2.0],
                   [7.0, 8.0, 9.0], [-1.0, -2.0, -3.0]])
F32 = [('x', 0, 7), ('y', 4, 7), ('z', 8, 7)]


def test_unorganized_float32_cloud():
    assert np.array_equal(cloud_xyz(write_cloud(POINTS, F32, 12)), POINTS)


def test_organized_cloud_row_by_row_with_padded_rows():
    cloud = write_cloud(POINTS, F32, 16, height=2, row_pad=5)
    assert (cloud.height, cloud.width, cloud.row_step) == (2, 3, 53)
    assert np.array_equal(cloud_xyz(cloud), POINTS)


def test_padding_float64_and_fields_in_another_order():
    # Ouster-like: intensity and ring first, z before y before x, 8 bytes of padding at the end
    fields = [('intensity', 0, 7), ('ring', 4, 4), ('z', 8, 8), ('y', 16, 8), ('x', 24, 8)]
    assert np.array_equal(cloud_xyz(write_cloud(POINTS, fields, 40)), POINTS)


def test_big_endian_and_mixed_datatypes():
    fields = [('x', 2, 7), ('y', 6, 8), ('z', 14, 3)]       # z a (truncated) INT16
    out = cloud_xyz(write_cloud(POINTS, fields, 17, big=True))
    assert np.array_equal(out[:, :2], POINTS[:, :2])
    assert np.array_equal(out[:, 2], np.trunc(POINTS[:, 2]))


def test_every_integer_datatype_reads_its_values():
    ints = np.array([[1, 2, 3], [100, 50, 0], [5, 6, 7]], dtype=float)
    for datatype in (1, 2, 3, 4, 5, 6):
        size = SIZES[datatype]
        fields = [('x', 0, datatype), ('y', size, datatype), ('z', 2 * size, datatype)]
        assert np.array_equal(cloud_xyz(write_cloud(ints, fields, 3 * size)), ints), datatype


def test_nan_points_are_kept_for_the_view_to_count():
    pts = POINTS.copy()
    pts[1] = np.nan
    out = cloud_xyz(write_cloud(pts, F32, 12))
    assert np.isnan(out[1]).all() and np.array_equal(out[[0, 2]], POINTS[[0, 2]])


def test_an_empty_cloud_has_no_points():
    assert cloud_xyz(PackedCloud(0, 0, tuple(CloudField(*f) for f in F32), False, 12, 0, b'')).shape == (0, 3)


def test_vendor_fields_of_unknown_datatype_are_ignored():
    cloud = write_cloud(POINTS, F32, 16)
    odd = PackedCloud(1, 6, cloud.fields + (CloudField('custom', 12, 42),), False, 16, 96, cloud.data)
    assert np.array_equal(cloud_xyz(odd), POINTS)


def test_packed_cloud_round_trip_organized():
    xyz = np.random.default_rng(0).normal(size=(4, 5, 3))
    xyz[1, 2] = np.nan
    cloud = pack_cloud(xyz, rings=np.repeat(np.arange(4)[:, None], 5, axis=1))
    assert (cloud.height, cloud.width, cloud.point_step, cloud.is_dense) == (4, 5, 32, False)
    assert np.allclose(cloud_xyz(cloud), xyz.reshape(-1, 3).astype(np.float32), equal_nan=True)


def replaced(cloud, **changes):
    fields = dict(cloud.__dict__)
    fields.update(changes)
    return PackedCloud(**fields)


GOOD = write_cloud(POINTS, F32, 16, height=2)


@pytest.mark.parametrize('changes, message', [
    (dict(fields=(CloudField('x', 0, 7), CloudField('y', 4, 7))), 'no z field'),
    (dict(fields=(CloudField('intensity', 0, 7),)), 'no x/y/z field'),
    (dict(fields=()), 'fields: none'),
    (dict(fields=(CloudField('x', 0, 9), CloudField('y', 4, 7), CloudField('z', 8, 7))), 'unknown datatype 9'),
    (dict(fields=(CloudField('x', 0, 7), CloudField('y', 4, 7), CloudField('z', 8, 7, 0))), 'count 0'),
    (dict(fields=(CloudField('x', 0, 7), CloudField('y', 4, 7), CloudField('z', 14, 7))), 'beyond point_step 16'),
    (dict(fields=(CloudField('x', 0, 7), CloudField('y', 4, 7), CloudField('z', 12, 8))),
     'FLOAT64 x 1 at offset 12) ends at byte 20'),
    (dict(fields=(CloudField('x', 0, 7), CloudField('y', 4, 7), CloudField('z', 8, 7), CloudField('rgb', 12, 7, 2))),
     'field rgb'),
    (dict(fields=(CloudField('x', -4, 7), CloudField('y', 4, 7), CloudField('z', 8, 7))), 'offset -4'),
    (dict(row_step=40), 'row_step 40 is less than width 3 x point_step 16'),
    (dict(point_step=0, row_step=0, data=b''), 'beyond point_step 0'),
    (dict(data=GOOD.data[:-1]), '95 bytes, but height 2 x row_step 48 = 96'),
    (dict(data=GOOD.data + b'\0'), '97 bytes'),
    (dict(height=3), '96 bytes, but height 3'),
    (dict(width=-1), 'width must be an integer >= 0'),
    (dict(row_step=48.0), 'row_step must be an integer'),
    (dict(data='not bytes'), 'not a byte buffer'),
])
def test_bad_layouts_are_refused_with_what_does_not_fit(changes, message):
    with pytest.raises(CloudError, match=message.replace('(', r'\(').replace(')', r'\)')):
        cloud_xyz(replaced(GOOD, **changes))


@pytest.mark.ros
def test_the_ros_message_wrapper_reads_the_layout_of_the_message():
    from builtin_interfaces.msg import Time
    from sensor_msgs.msg import PointCloud2, PointField

    from global_loc.ros.cloud import cloud_from_msg, cloud_to_msg
    odd = write_cloud(POINTS, [('z', 0, 8), ('x', 8, 7), ('y', 12, 7)], 20, big=True, height=2, row_pad=3)
    msg = PointCloud2(height=odd.height, width=odd.width, is_bigendian=True, point_step=odd.point_step,
                      row_step=odd.row_step, is_dense=True,
                      fields=[PointField(name=f.name, offset=f.offset, datatype=f.datatype, count=1)
                              for f in odd.fields])
    msg.data = odd.data
    assert np.array_equal(cloud_from_msg(msg), POINTS)
    back = cloud_to_msg(POINTS, 'lidar', Time(sec=3))
    assert back.header.frame_id == 'lidar' and back.width == 6 and back.height == 1
    assert np.allclose(cloud_from_msg(back), POINTS)
    msg.fields = msg.fields[1:]
    with pytest.raises(CloudError, match='no z field'):
        cloud_from_msg(msg)
