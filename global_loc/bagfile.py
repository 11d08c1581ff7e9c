"""LaserScans from a rosbag2 recording (sqlite3 or mcap storage), read with the `rosbags`
library: offline localization of a recorded run without a ROS installation."""
from __future__ import annotations

from collections.abc import Iterator

from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from .core.scan import Scan

LASER_SCAN = 'sensor_msgs/msg/LaserScan'


class BagError(ValueError):
    """The recording cannot be read, or has no LaserScans on the topic; the message says which."""


def read_scans(path: str, topic: str, every: int = 1) -> Iterator[tuple[int, Scan]]:
    """(index on the topic, Scan with the header's stamp) of every `every`-th LaserScan on `topic`."""
    if every < 1:
        raise BagError(f'--every must be at least 1, got {every}')
    try:
        reader = Reader(path)
        reader.open()
    except Exception as e:      # rosbags raises several types for a missing or malformed recording
        raise BagError(f'{path}: not a readable rosbag2 recording ({type(e).__name__}: {e})') from None
    try:
        connections = [c for c in reader.connections if c.topic == topic]
        if not connections:
            topics = ', '.join(sorted({f'{c.topic} ({c.msgtype})' for c in reader.connections})) or 'none'
            raise BagError(f'{path}: no topic {topic}; the recording has: {topics}')
        other = sorted({c.msgtype for c in connections} - {LASER_SCAN})
        if other:
            raise BagError(f'{path}: {topic} carries {", ".join(other)}, not {LASER_SCAN}')
        typestore = get_typestore(Stores.ROS2_JAZZY)
        for index, (connection, _, raw) in enumerate(reader.messages(connections=connections)):
            if index % every:
                continue
            msg = typestore.deserialize_cdr(raw, connection.msgtype)
            yield index, Scan(float(msg.angle_min), float(msg.angle_increment), float(msg.range_min),
                              float(msg.range_max), msg.ranges.astype(float),
                              msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)
    finally:
        reader.close()
