"""sensor_msgs/PointCloud2 <-> core.cloud: the message's layout fields copied over, the
reading and checking done in the core."""
from __future__ import annotations

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField

from ..core.cloud import cloud_xyz, pack_cloud
from ..io.messages import packed_from_msg


def cloud_from_msg(msg: PointCloud2) -> np.ndarray:
    """(N, 3) x/y/z in the message's frame; CloudError for a layout that does not fit."""
    return cloud_xyz(packed_from_msg(msg))


def cloud_to_msg(xyz: np.ndarray, frame_id: str, stamp, rings: np.ndarray | None = None) -> PointCloud2:
    """An organized (H, W, 3) or unorganized (N, 3) cloud in Velodyne's layout (core.cloud.pack_cloud)."""
    packed = pack_cloud(xyz, rings)
    msg = PointCloud2(height=packed.height, width=packed.width, is_bigendian=packed.is_bigendian,
                      point_step=packed.point_step, row_step=packed.row_step, is_dense=packed.is_dense)
    msg.fields = [PointField(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in packed.fields]
    msg.data = packed.data
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    return msg
