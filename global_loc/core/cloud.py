"""sensor_msgs/PointCloud2 without ROS: the message's fields as a plain type, its x/y/z
read as an (N, 3) array, and the inverse for the simulator.

Where x, y and z sit in a point is whatever the driver's PointField list says (offset,
datatype, is_bigendian, point_step; Velodyne pads to 32 bytes, Ouster puts x/y/z after
other fields, some drivers send float64), so they are read through a numpy structured
dtype built from that list - strided over the data, no Python loop per point - and the
layout is checked against the data first: a wrong one gets a CloudError saying what
does not fit, never points read from the wrong bytes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# PointField datatype constants -> (name, numpy type code)
DATATYPES = {1: ('INT8', 'i1'), 2: ('UINT8', 'u1'), 3: ('INT16', 'i2'), 4: ('UINT16', 'u2'),
             5: ('INT32', 'i4'), 6: ('UINT32', 'u4'), 7: ('FLOAT32', 'f4'), 8: ('FLOAT64', 'f8')}
XYZ = ('x', 'y', 'z')


class CloudError(ValueError):
    """A point cloud cannot be read: no x/y/z field, or a layout that does not fit its data."""


@dataclass(frozen=True)
class CloudField:
    name: str
    offset: int
    datatype: int
    count: int = 1


@dataclass(frozen=True)
class PackedCloud:
    """The PointCloud2 fields the points are read from (header aside)."""
    height: int
    width: int
    fields: tuple          # CloudField per PointField
    is_bigendian: bool
    point_step: int
    row_step: int
    data: object           # bytes, bytearray, memoryview, array.array('B'), uint8 ndarray
    is_dense: bool = False

    @property
    def num_points(self) -> int:
        return self.height * self.width


def cloud_xyz(cloud: PackedCloud) -> np.ndarray:
    """(height x width, 3) float64 x/y/z of every point, row by row (an organized cloud's
    invalid points stay NaN: the view drops them and counts them). CloudError when the
    cloud has no x/y/z field or its layout does not fit its data."""
    xyz_fields = _xyz_fields(cloud)
    data = _check_layout(cloud)
    if cloud.num_points == 0:
        return np.empty((0, 3))
    order = '>' if cloud.is_bigendian else '<'
    dtype = np.dtype({'names': list(XYZ), 'formats': [order + DATATYPES[f.datatype][1] for f in xyz_fields],
                      'offsets': [f.offset for f in xyz_fields], 'itemsize': cloud.point_step})
    points = np.ndarray((cloud.height, cloud.width), dtype=dtype, buffer=data,
                        strides=(cloud.row_step, cloud.point_step))
    return np.stack([points[n].astype(np.float64) for n in XYZ], axis=-1).reshape(-1, 3)


def _xyz_fields(cloud: PackedCloud) -> list:
    """The x, y and z fields, each readable (known datatype, at least one element)."""
    by_name = {}
    for f in cloud.fields:
        by_name.setdefault(f.name, f)
    missing = [n for n in XYZ if n not in by_name]
    if missing:
        raise CloudError(f'point cloud has no {"/".join(missing)} field (fields: '
                         f'{", ".join(f.name for f in cloud.fields) or "none"})')
    for n in XYZ:
        f = by_name[n]
        if f.datatype not in DATATYPES:
            raise CloudError(f'point cloud field {n} has unknown datatype {f.datatype} '
                             f'(PointField INT8=1 .. FLOAT64=8)')
        if f.count < 1:
            raise CloudError(f'point cloud field {n} has count {f.count}: no value to read')
    return [by_name[n] for n in XYZ]


def _check_layout(cloud: PackedCloud):
    """The data as a byte buffer, once every known field lies within point_step, a row's
    points within row_step, and the data is exactly height x row_step bytes."""
    for name in ('height', 'width', 'point_step', 'row_step'):
        value = getattr(cloud, name)
        if not isinstance(value, (int, np.integer)) or value < 0:
            raise CloudError(f'point cloud {name} must be an integer >= 0, got {value!r}')
    for f in cloud.fields:
        if f.datatype not in DATATYPES:
            continue        # a vendor's field we do not read; x/y/z were checked already
        name, code = DATATYPES[f.datatype]
        end = f.offset + np.dtype(code).itemsize * max(f.count, 1)
        if f.offset < 0 or end > cloud.point_step:
            raise CloudError(f'point cloud field {f.name} ({name} x {f.count} at offset {f.offset}) ends at byte '
                             f'{end}, beyond point_step {cloud.point_step}')
    if cloud.row_step < cloud.width * cloud.point_step:
        raise CloudError(f'point cloud row_step {cloud.row_step} is less than width {cloud.width} x point_step '
                         f'{cloud.point_step} = {cloud.width * cloud.point_step}')
    try:
        data = np.frombuffer(cloud.data, dtype=np.uint8)
    except (TypeError, ValueError) as e:
        raise CloudError(f'point cloud data is not a byte buffer: {e}') from None
    if data.size != cloud.height * cloud.row_step:
        raise CloudError(f'point cloud data has {data.size} bytes, but height {cloud.height} x row_step '
                         f'{cloud.row_step} = {cloud.height * cloud.row_step}')
    return data


def pack_cloud(xyz: np.ndarray, rings: np.ndarray | None = None) -> PackedCloud:
    """A cloud laid out as Velodyne's driver does: float32 x/y/z at bytes 0/4/8, a uint16
    ring at 16, 32 bytes a point. `xyz`: (H, W, 3) organized (rings: (H, W)) or (N, 3)."""
    xyz = np.asarray(xyz, dtype=float)
    if xyz.ndim == 2:
        xyz = xyz[None]
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise CloudError(f'points to pack must be (N, 3) or (H, W, 3), got {xyz.shape}')
    height, width = xyz.shape[:2]
    dtype = np.dtype({'names': ['x', 'y', 'z', 'ring'], 'formats': ['<f4', '<f4', '<f4', '<u2'],
                      'offsets': [0, 4, 8, 16], 'itemsize': 32})
    packed = np.zeros((height, width), dtype=dtype)
    for i, n in enumerate(XYZ):
        packed[n] = xyz[..., i]
    packed['ring'] = 0 if rings is None else np.asarray(rings).reshape(height, width)
    fields = (CloudField('x', 0, 7), CloudField('y', 4, 7), CloudField('z', 8, 7), CloudField('ring', 16, 4))
    return PackedCloud(height, width, fields, False, 32, 32 * width, packed.tobytes(),
                       bool(np.isfinite(xyz).all()))
