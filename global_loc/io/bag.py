"""LaserScans from a rosbag2 recording (sqlite3 or mcap storage), read with the `rosbags`
library: offline localization of a recorded run without a ROS installation; and the laser's
mounting on the robot base from the recording's /tf_static and /tf."""
from __future__ import annotations

import functools
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from ..core.frames import compose, transform_matrix
from ..core.mount import LaserMount, MountError
from ..core.mount3d import Mount3D
from ..core.scan import Scan
from ..core.transform import Rigid2D
from .messages import frame_name, pose_from_msg, scan_from_msg, stamp_seconds, transform_from_msg


@functools.cache
def _typestore():
    return get_typestore(Stores.ROS2_JAZZY)


def decode(raw: bytes, msgtype: str):
    """A recorded message (its CDR bytes and type name) as a message object: rosbags' ROS 2
    Jazzy types, read here only."""
    return _typestore().deserialize_cdr(raw, msgtype)

LASER_SCAN = 'sensor_msgs/msg/LaserScan'
ODOMETRY = 'nav_msgs/msg/Odometry'
TF_MESSAGE = 'tf2_msgs/msg/TFMessage'
TF_TOPICS = ('/tf_static', '/tf')
# A /tf transform whose translation and rotation stay within these over the whole
# recording is static in practice (a URDF joint published by robot_state_publisher).
STATIC_M, STATIC_QUATERNION = 1e-6, 1e-6


class BagError(ValueError):
    """The recording cannot be read, or has no LaserScans on the topic; the message says which."""


class MountingNotFound(Exception):
    """The recording does not say where the laser sits on the base; the message says why."""


@dataclass(frozen=True)
class BagMounting:
    mount: LaserMount          # the laser on the base, seen from above, and whether it is upside down
    source: str                # the topics it was read from, e.g. '/tf_static'
    chain: str                 # the frames it composes, e.g. 'base_link -> shell_link -> rplidar_link'

    @property
    def base_T_laser(self) -> Rigid2D:
        return self.mount.base_T_laser


def open_bag(path: str) -> Reader:
    try:
        reader = Reader(path)
        reader.open()
    except Exception as e:      # rosbags raises several types for a missing or malformed recording
        raise BagError(f'{path}: not a readable rosbag2 recording ({type(e).__name__}: {e})') from None
    return reader


def scan_connections(reader: Reader, path: str, topic: str, msgtype: str = LASER_SCAN) -> list:
    connections = [c for c in reader.connections if c.topic == topic]
    if not connections:
        topics = ', '.join(sorted({f'{c.topic} ({c.msgtype})' for c in reader.connections})) or 'none'
        raise BagError(f'{path}: no topic {topic}; the recording has: {topics}')
    other = sorted({c.msgtype for c in connections} - {msgtype})
    if other:
        raise BagError(f'{path}: {topic} carries {", ".join(other)}, not {msgtype}')
    return connections


def read_scans(path: str, topic: str, every: int = 1) -> Iterator[tuple[int, Scan]]:
    """(index on the topic, Scan with the header's stamp) of every `every`-th LaserScan on `topic`."""
    if every < 1:
        raise BagError(f'--every must be at least 1, got {every}')
    reader = open_bag(path)
    try:
        connections = scan_connections(reader, path, topic)
        for index, (connection, _, raw) in enumerate(reader.messages(connections=connections)):
            if index % every:
                continue
            yield index, scan_from_msg(decode(raw, connection.msgtype))
    finally:
        reader.close()


def read_odometry(path: str, topic: str) -> list[tuple[float, Rigid2D]]:
    """(stamp, base pose) of each of the nav_msgs/Odometry messages on `topic`, by header stamp."""
    reader = open_bag(path)
    try:
        connections = [c for c in reader.connections if c.topic == topic]
        if not connections or any(c.msgtype != ODOMETRY for c in connections):
            found = ', '.join(sorted({f'{c.topic} ({c.msgtype})' for c in reader.connections})) or 'none'
            raise BagError(f'{path}: no {ODOMETRY} on {topic} (--odom-topic); the recording has: {found}')
        poses = []
        for connection, _, raw in reader.messages(connections=connections):
            msg = decode(raw, connection.msgtype)
            poses.append((stamp_seconds(msg.header.stamp), pose_from_msg(msg.pose.pose)))
    finally:
        reader.close()
    return sorted(poses, key=lambda stamped: stamped[0])


def read_mounting(path: str, topic: str, base_frame: str) -> BagMounting:
    """The pose on `base_frame` of the frame the first LaserScan on `topic` was taken in,
    composed from /tf_static and the /tf transforms that never change in the recording.
    MountingNotFound (with the reason) when the recording does not have it; BagError when
    the recording is unreadable or the laser is not level."""
    found = read_mountings(path, {topic: LASER_SCAN}, base_frame)[topic]
    if isinstance(found, MountingNotFound):
        raise found
    return BagMounting(planar_mount(found.matrix, frame_name(base_frame), found.frame), found.source, found.chain)


@dataclass(frozen=True)
class BagMount3D:
    """A sensor's full 3D mounting on the base as the recording's tf gives it."""
    mount: Mount3D
    matrix: np.ndarray         # 4x4 base_T_sensor
    frame: str                 # the sensor's frame (its messages' frame_id)
    source: str                # the topics it was read from
    chain: str                 # the frames it composes

    def as_dict(self) -> dict:
        return {'from': self.source, 'frames': self.chain,
                **dict(zip(('x', 'y', 'z', 'roll', 'pitch', 'yaw'), (round(v, 6) for v in self.mount.as_tuple()),
                           strict=True))}


def read_mountings(path: str, topics: dict, base_frame: str) -> dict:
    """topic -> BagMount3D, or the MountingNotFound saying why not, of each topic's sensor
    (`topics`: topic -> its message type): the frame of its first message on `base_frame`,
    composed from /tf_static and the /tf transforms that never change in the recording.
    BagError when the recording is unreadable or a topic is missing or of another type."""
    reader = open_bag(path)
    try:
        frames = {}
        for topic, msgtype in topics.items():
            first = next(reader.messages(connections=scan_connections(reader, path, topic, msgtype)), None)
            frames[topic] = None if first is None else frame_name(
                decode(first[2], first[0].msgtype).header.frame_id)
        parents, sources, moving = static_transforms(reader)
    finally:
        reader.close()
    found = {}
    for topic, frame in frames.items():
        try:
            if frame is None:
                raise MountingNotFound(f'no message on {topic}')
            if not frame:
                raise MountingNotFound(f'the messages on {topic} have no frame_id')
            found[topic] = chain_mount(parents, sources, moving, frame, frame_name(base_frame))
        except MountingNotFound as e:
            found[topic] = e
    return found


def chain_mount(parents: dict, sources: dict, moving: set, frame: str, base_frame: str) -> BagMount3D:
    """`frame` on `base_frame` through the fixed transforms (static_transforms' answer)."""
    ignored = f' ({", ".join(sorted(moving))} on /tf move during the recording)' if moving else ''
    if not parents and frame != base_frame:
        raise MountingNotFound(f'no transforms on {" or ".join(TF_TOPICS)} that stay fixed{ignored}')
    chain = compose(parents, base_frame, frame)
    if chain is None:
        raise MountingNotFound(f'no chain of fixed transforms from {base_frame} to the sensor frame {frame} '
                               f'on {" or ".join(TF_TOPICS)}{ignored}')
    used = {sources[f] for f in chain.composed}
    return BagMount3D(Mount3D.from_matrix(chain.base_T_frame), chain.base_T_frame, frame,
                      ', '.join(sorted(used)) or f'the messages\' frame_id is {base_frame}', ' -> '.join(chain.frames))


def static_transforms(reader: Reader) -> tuple[dict, dict, set]:
    """child frame -> (parent frame, 4x4 parent_T_child) of every /tf_static transform and
    every /tf one that stays fixed; child frame -> the topic it came from; the /tf children
    whose transform moves."""
    seen: dict[str, dict] = {topic: {} for topic in TF_TOPICS}
    moving = set()
    connections = [c for c in reader.connections if c.topic in TF_TOPICS and c.msgtype == TF_MESSAGE]
    # (rosbags reads every topic when given no connections)
    for connection, _, raw in reader.messages(connections=connections) if connections else ():
        for t in decode(raw, connection.msgtype).transforms:
            child, parent, translation, quaternion = transform_from_msg(t)
            value = (parent, translation, quaternion)
            known = seen[connection.topic].setdefault(child, value)
            if connection.topic == '/tf' and not same_transform(known, value):
                moving.add(child)
    fixed = {**{c: v for c, v in seen['/tf'].items() if c not in moving}, **seen['/tf_static']}
    parents = {child: (parent, matrix(translation, quaternion)) for child, (parent, translation, quaternion)
               in fixed.items()}
    sources = {child: '/tf_static' if child in seen['/tf_static'] else '/tf' for child in fixed}
    return parents, sources, {f'{seen["/tf"][c][0]} -> {c}' for c in moving}


def same_transform(a, b) -> bool:
    quaternion_close = min(np.abs(a[2] - b[2]).max(), np.abs(a[2] + b[2]).max()) <= STATIC_QUATERNION
    return a[0] == b[0] and np.abs(a[1] - b[1]).max() <= STATIC_M and quaternion_close


def matrix(translation, quaternion) -> np.ndarray:
    """4x4 homogeneous transform of a recorded translation and rotation quaternion (x, y, z, w)."""
    try:
        return transform_matrix(translation, quaternion)
    except ValueError:
        raise BagError(f'a transform in the recording is not finite or has a zero quaternion: '
                       f'{translation.tolist()}, {quaternion.tolist()}') from None


def planar_mount(base_T_laser: np.ndarray, base_frame: str, laser_frame: str) -> LaserMount:
    """The laser's mounting as a 2-D method uses it (core/mount.py: upright or upside down);
    BagError when the bag's tf tilts it out of the horizontal plane."""
    try:
        return LaserMount.from_rotation(base_T_laser[0, 3], base_T_laser[1, 3], base_T_laser[:3, :3])
    except MountError as e:
        raise BagError(f'the bag\'s tf mounts {laser_frame} on {base_frame} so: {e}') from None
