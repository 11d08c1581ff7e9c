"""`python -m global_loc localize --bag B --topic /scan --topic /scan_rear --cloud-topic /points`:
several sensors of a recording merged into one view as the server merges them (core.view,
ros/sensors.py), without ROS.

For each (every N-th) message of the first topic, every other topic's newest message
stamped no later than merge_window_s after it: what the server would hold after waiting
the window for the other sensors. merge_view then leaves out the ones too old or with a
clock far apart, saying why. Offline a message's stamp is its arrival. Each sensor's
mounting comes from the bag's /tf_static and fixed /tf transforms where they have its
frame, else from `--mount TOPIC X Y Z ROLL PITCH YAW`, else - the first topic only - from
--laser-x/--laser-y/--laser-yaw (the server's laser_* parameters); a sensor with none is
left out, saying so. The bag's odometry (--odom-topic), when it has one, moves each reading
to the view's stamp. One JSON line per view with the sensors that contributed, those left
out and why.
"""
from __future__ import annotations

import bisect
import json
import math
import sys
from dataclasses import dataclass

from ..core.mount3d import Mount3D, Mount3DError
from ..core.outcome import Outcome
from ..core.pose_history import PoseHistory
from ..core.scan import ScanError
from ..core.view import SensorReading, ViewConfig, ViewError, merge_view
from ..io.bag import (
    LASER_SCAN,
    BagError,
    MountingNotFound,
    decode,
    open_bag,
    read_mountings,
    read_odometry,
    scan_connections,
)
from ..io.messages import reading_from_msg, stamp_seconds

POINT_CLOUD2 = 'sensor_msgs/msg/PointCloud2'


@dataclass(frozen=True)
class BagSensor:
    topic: str
    msgtype: str                      # LASER_SCAN or POINT_CLOUD2
    mount: Mount3D | None             # None: nobody says where it sits (left out)
    mounting: dict                    # where the mount came from, for the output line


def mount_flags(values) -> dict:
    """topic -> Mount3D of the `--mount TOPIC X Y Z ROLL PITCH YAW` flags; ValueError when bad."""
    mounts = {}
    for topic, *numbers in values or []:
        try:
            mounts[topic] = Mount3D.from_values(numbers)
        except Mount3DError as e:
            raise ValueError(f'--mount {topic}: {e}') from None
    return mounts


def bag_sensors(args) -> list[BagSensor]:
    """The sensors of the command line with their mountings (tf first, as the server)."""
    topics = {**{t: LASER_SCAN for t in args.topic}, **{t: POINT_CLOUD2 for t in args.cloud_topic or []}}
    if len(topics) != len(args.topic) + len(args.cloud_topic or []):
        raise ValueError(f'a topic is given twice: --topic {args.topic} --cloud-topic {args.cloud_topic}')
    flags = mount_flags(args.mount)
    unknown = sorted(set(flags) - set(topics))
    if unknown:
        raise ValueError(f'--mount for {", ".join(unknown)}, which is no --topic or --cloud-topic')
    found = read_mountings(args.bag, topics, args.base_frame)
    sensors = []
    for i, (topic, msgtype) in enumerate(topics.items()):
        tf = found[topic]
        if not isinstance(tf, MountingNotFound):
            if topic in flags:
                print(f'note: {topic}\'s mounting comes from the bag ({tf.source}: {tf.chain}); its --mount is '
                      'not used', file=sys.stderr)
            sensors.append(BagSensor(topic, msgtype, tf.mount, tf.as_dict()))
            continue
        because = {'because': f'the bag has no mounting of {topic} on {args.base_frame}: {tf}'}
        if topic in flags:
            sensors.append(BagSensor(topic, msgtype, flags[topic], {'from': '--mount', **because}))
        elif i == 0 and msgtype == LASER_SCAN:     # the primary laser, as the server's laser_* parameters
            mount = Mount3D(args.laser_x or 0.0, args.laser_y or 0.0, 0.0, 0.0, 0.0, args.laser_yaw or 0.0)
            sensors.append(BagSensor(topic, msgtype, mount, {'from': '--laser-x/--laser-y/--laser-yaw', **because}))
        else:
            sensors.append(BagSensor(topic, msgtype, None, {'from': None, **because}))
    return sensors


def read_stamps(path: str, sensors: list[BagSensor]) -> dict:
    """topic -> [(stamp, connection, raw)] by stamp, for every sensor's messages."""
    reader = open_bag(path)
    try:
        connections = {s.topic: scan_connections(reader, path, s.topic, s.msgtype) for s in sensors}
        messages = {s.topic: [] for s in sensors}
        for connection, _, raw in reader.messages(connections=[c for cs in connections.values() for c in cs]):
            msg = decode(raw, connection.msgtype)
            messages[connection.topic].append((stamp_seconds(msg.header.stamp), connection.msgtype, raw))
    finally:
        reader.close()
    for found in messages.values():
        found.sort(key=lambda m: m[0])
    if not messages[sensors[0].topic]:
        raise BagError(f'{path}: no message on {sensors[0].topic}, the first topic')
    return messages


def bag_odometry(path: str, topic: str) -> tuple[PoseHistory | None, str]:
    """The recording's odometry as a PoseHistory, or None and why not."""
    try:
        poses = read_odometry(path, topic)
    except BagError as e:
        return None, f'none: {e}'
    history = PoseHistory(keep_s=math.inf)
    for stamp, pose in poses:
        history.add(stamp, pose)
    return history, f'{topic} ({len(poses)} poses)'


def reading_of(sensor: BagSensor, message) -> SensorReading:
    """One recorded message as a SensorReading; ViewError (the reason) when it is unusable."""
    if sensor.mount is None:
        raise ViewError(f'no mounting: {sensor.mounting["because"]}, and no --mount {sensor.topic} X Y Z ROLL '
                        'PITCH YAW')
    msg = decode(message[2], message[1])
    return reading_from_msg(sensor.topic, sensor.msgtype == LASER_SCAN, msg, lambda: sensor.mount)


def views(sensors: list[BagSensor], messages: dict, every: int, config: ViewConfig, odometry):
    """(where, View or the ViewError) per every-th message of the first sensor."""
    if every < 1:
        raise BagError(f'--every must be at least 1, got {every}')
    stamps = {topic: [m[0] for m in found] for topic, found in messages.items()}
    first = sensors[0].topic
    for index, start in enumerate(messages[first]):
        if index % every:
            continue
        readings, reasons = {}, {}
        for sensor in sensors:
            found = messages[sensor.topic]
            at = index if sensor.topic == first else bisect.bisect_right(
                stamps[sensor.topic], start[0] + config.merge_window_s) - 1
            if at < 0:
                reasons[sensor.topic] = 'silent: no message by the window\'s end'
                continue
            try:
                readings[sensor.topic] = reading_of(sensor, found[at])
            except (ScanError, Mount3DError) as e:       # ViewError, ScanError, MountError
                reasons[sensor.topic] = f'{type(e).__name__}: {e}'
        where = {'index': index, 'stamp': round(start[0], 9)}
        try:
            yield where, merge_view(readings, odometry, config=config, unread=reasons)
        except ViewError as e:
            yield where, e


def localize_views(args, localizer, method: str, result_fields) -> int:
    """`localize --bag` with several sensors: one JSON line per view."""
    config = ViewConfig(merge_window_s=args.merge_window)
    sensors = bag_sensors(args)
    messages = read_stamps(args.bag, sensors)
    odometry, odometry_said = bag_odometry(args.bag, args.odom_topic)
    mounting = {s.topic: s.mounting for s in sensors}
    for where, view in views(sensors, messages, args.every, config, odometry):
        out = {**where, 'method': method, 'mounting': mounting, 'odometry': odometry_said}
        if isinstance(view, ViewError):
            print(json.dumps({**out, 'outcome': Outcome.UNUSABLE_SCAN.label, 'error': str(view)}), flush=True)
            continue
        out['view'] = {'contributed': view.contributed, 'left_out': view.left_out, 'points': len(view.points.points),
                       'motion_compensated': view.motion_compensated}
        try:
            result = localizer.localize_points(view.points, args.method, base_T_laser=view.base_T_laser)
        except ScanError as e:
            print(json.dumps({**out, 'outcome': Outcome.UNUSABLE_SCAN.label, 'error': str(e)}), flush=True)
            continue
        print(json.dumps({**out, **result_fields(result)}), flush=True)
    return 0
