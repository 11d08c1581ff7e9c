"""The server's sensors: every configured LaserScan and PointCloud2 topic, the
newest message of each with its arrival time, each one's mounting on the base, and the
view a request localizes (core.view.merge_view).

A sensor's mounting comes from tf when it has base_frame <- the message's frame - tf2_ros
when it is importable, else the static transforms received on /tf_static
(ros/tf_static.py: what robot_state_publisher publishes from a URDF, without tf2_ros) -
else from the parameter `sensors.<name>.mount` (x y z roll pitch yaw; <name> is the topic
without its leading slash, other slashes as underscores - nav2's obstacle layer keys its
per-source parameters by a source name the same way), else, for the primary laser (the
first scan topic) only, from laser_x/laser_y/laser_yaw/laser_roll. A sensor with none of
them is left out of the view, saying so. tf comes first, as it did with tf2 alone
(docs/decisions/0022): a parameter that says otherwise is named in the log line that says
a mounting came from /tf_static. Each lookup reads what has arrived (never waits), so a
/tf_static that arrives late is used from the next message on.

A request's view waits for the first message that arrives after the request, then up to
merge_window_s for the other sensors; a sensor with nothing since the request is left
out ("silent"), and so is one whose message cannot be read (the reason said), on the
result and on /diagnostics."""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from ..core.motion import pose_fitter
from ..core.mount import LaserMount, MountError
from ..core.mount3d import Mount3D, Mount3DError
from ..core.outcome import CanceledError
from ..core.scan import ScanError, scan_to_points
from ..core.view import SensorReading, View, ViewConfig, ViewError, merge_view
from ..io.messages import reading_from_msg, scan_from_msg
from .tf_static import subscribe_static_transforms

SCAN, CLOUD = 'scan', 'cloud'


def sensor_name(topic: str) -> str:
    """`/robot/scan_rear` -> `robot_scan_rear`: the key of the sensor's parameters."""
    return topic.strip('/').replace('/', '_')


@dataclass(frozen=True)
class SensorSpec:
    topic: str
    kind: str                          # SCAN or CLOUD
    mount: Optional[Mount3D] = None    # sensors.<name>.mount; None: not set
    primary: bool = False              # the first laser: laser_* parameters, the watch, resolve-by-motion

    @property
    def mount_parameter(self) -> str:
        return f'sensors.{sensor_name(self.topic)}.mount'


def check_mount_value(value) -> Optional[str]:
    """Why `value` is no sensors.<name>.mount (six finite numbers), None when it is one."""
    try:
        Mount3D.from_values(value)
    except Mount3DError as e:
        return str(e)
    return None


def sensor_specs(scan_topics, scan_topic: str, cloud_topics, mounts: dict) -> tuple:
    """The sensors the parameters configure; ValueError starting with the parameter's name."""
    scan_topics, cloud_topics = list(scan_topics or []), list(cloud_topics or [])
    if scan_topic:      # the one-laser alias
        if scan_topics not in (['/scan'], [scan_topic]):
            raise ValueError(f'scan_topic: {scan_topic!r} is the one-laser alias of scan_topics, which is set '
                             f'too ({scan_topics}): set one of them')
        scan_topics = [scan_topic]
    topics = scan_topics + cloud_topics
    if not topics:
        raise ValueError('scan_topics: no sensor: scan_topics and cloud_topics are both empty')
    for topic in topics:
        if not isinstance(topic, str) or not sensor_name(topic):
            raise ValueError(f'scan_topics/cloud_topics: {topic!r} is not a topic name')
    if len(set(map(sensor_name, topics))) != len(topics):
        raise ValueError(f'scan_topics/cloud_topics: a topic appears twice (or two differ only in slashes): {topics}')
    specs = []
    for i, topic in enumerate(topics):
        spec = SensorSpec(topic, SCAN if i < len(scan_topics) else CLOUD, None, i == 0 and bool(scan_topics))
        value = mounts.get(topic)
        if value is not None:
            try:
                value = value if isinstance(value, Mount3D) else Mount3D.from_values(value)
            except Mount3DError as e:
                raise ValueError(f'{spec.mount_parameter}: {e}') from None
        specs.append(SensorSpec(spec.topic, spec.kind, value, spec.primary))
    return tuple(specs)


class NoMounting(ViewError):
    """A sensor whose mounting nobody gives (no tf, no parameter)."""


class SensorMounts:
    """Each sensor's mounting: tf (tf2_ros when importable, else the /tf_static reader)
    when it has it, else the parameters."""

    def __init__(self, node, guarded: Callable = lambda f: f):
        self.node = node
        self.base_frame, self.laser_fallback = 'base_link', Mount3D()
        self.buffer = self.static = None
        self.told: dict = {}            # topic -> the /tf_static mounting last logged for it
        try:
            import tf2_ros
        except ImportError:
            self.static = subscribe_static_transforms(node, guarded)
            node.get_logger().info(
                f'tf2_ros not available: sensor mountings come from '
                f'{"the static transforms on /tf_static, else " if self.static else "(no tf2_msgs either) "}'
                f'the sensors.<name>.mount parameters (the primary laser: laser_x/laser_y/laser_yaw/laser_roll)')
            return
        self.buffer = tf2_ros.Buffer()
        self.listener = tf2_ros.TransformListener(self.buffer, node)

    def configure(self, config) -> None:
        """New parameters (configure, or a live laser_* change)."""
        self.base_frame = config['base_frame']
        self.laser_fallback = Mount3D(config['laser_x'], config['laser_y'], 0.0, config['laser_roll'], 0.0,
                                      config['laser_yaw'])
        self.told = {}

    def mount(self, spec: SensorSpec, frame: str) -> Mount3D:
        """`spec`'s mounting for a message in `frame`; NoMounting when there is none."""
        from_tf = self.from_tf(spec, frame)
        if from_tf is not None:
            return from_tf
        if spec.mount is not None:
            return spec.mount
        if spec.primary:
            return self.laser_fallback
        raise NoMounting(f'no mounting: no tf {self.base_frame} <- {frame or "(no frame_id)"} and no parameter '
                         f'{spec.mount_parameter} [x, y, z, roll, pitch, yaw]')

    def from_tf(self, spec: SensorSpec, frame: str) -> Optional[Mount3D]:
        """base_frame <- `frame` from tf2 or /tf_static; None when tf does not have it (yet)."""
        if not frame:
            return None
        if self.buffer is not None:
            try:
                t = self.buffer.lookup_transform(self.base_frame, frame, _latest()).transform
            except Exception:   # tf2 raises several types; any means "not known"
                return None
            p, q = t.translation, t.rotation
            return Mount3D.from_quaternion(p.x, p.y, p.z, q)
        found = self.static.lookup(self.base_frame, frame) if self.static is not None else None
        if found is None:
            return None
        mount, chain = found
        if self.told.get(spec.topic) != mount:
            self.told[spec.topic] = mount
            self.node.get_logger().info(f'{spec.topic}: mounting from /tf_static ({chain}): {mount.describe()}'
                                        f'{self.overridden(spec, mount)}')
        return mount

    def overridden(self, spec: SensorSpec, mount: Mount3D) -> str:
        """What the log line adds when a parameter set for `spec` says otherwise than tf."""
        def differs(other: Mount3D) -> bool:
            return not np.allclose(other.matrix(), mount.matrix(), atol=1e-3)
        if spec.mount is not None and differs(spec.mount):
            return f'; {spec.mount_parameter} says {spec.mount.describe()}, but tf comes first'
        if spec.primary and spec.mount is None and self.laser_fallback != Mount3D() and differs(self.laser_fallback):
            return f'; laser_x/laser_y/laser_yaw/laser_roll say {self.laser_fallback.describe()}, but tf comes first'
        return ''

    def laser_mount(self, specs: tuple, frame: str) -> LaserMount:
        """The primary laser's mounting as the 2D methods take it (MountError: tilted, none)."""
        primary = next((s for s in specs if s.primary), None)
        if primary is None:
            raise MountError('no laser configured (scan_topics is empty)')
        return LaserMount.from_mount3d(self.mount(primary, frame))


def laser_fit(tracker, laser_mount: Callable, scan_msg, pose):
    """The tracker's fit of a primary-laser scan at a base pose (the health watch's); None when the
    scan or its mounting cannot be used."""
    try:
        mount = laser_mount(scan_msg.header.frame_id)
        points = scan_to_points(mount.upright(scan_from_msg(scan_msg)))
    except ScanError:
        return None
    return pose_fitter(tracker, points, mount.base_T_laser)(pose)[0]


def _latest():
    from rclpy.time import Time
    return Time()


class SensorInputs:
    """The newest message of every configured sensor, with when it arrived; the request's
    wait for a view; what went wrong per sensor (for /diagnostics)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic):
        self.clock = clock
        self.cond = threading.Condition()
        self.specs: tuple = ()
        self.newest: dict = {}             # topic -> (arrival, msg)
        self.problems: dict = {}           # topic -> why its last message could not be used
        self.last_view = ''

    def configure(self, specs: tuple) -> None:
        with self.cond:
            self.specs, self.newest, self.problems = specs, {}, {}

    def put(self, topic: str, msg) -> None:
        with self.cond:
            self.newest[topic] = (self.clock(), msg)
            self.cond.notify_all()

    def wait(self, since: float, timeout: float, window: float, cancelled=lambda: False,
             poll_s: float = 0.05) -> Optional[dict]:
        """Once the first message after `since` has arrived, and every sensor's or
        `window` s have followed it: topic -> (arrival, msg) of every sensor heard from
        (older ones too: `view` tells them apart). None when nothing arrived by since +
        timeout; CanceledError when `cancelled()` says so."""
        first = None       # when the first message after `since` arrived (a sensor's newest keeps moving)
        with self.cond:
            while True:
                fresh = [a for a, _ in self.newest.values() if a >= since]
                now = self.clock()
                if fresh and first is None:
                    first = min(fresh)
                if fresh and (len(fresh) == len(self.specs) or now >= first + window):
                    return dict(self.newest)
                if cancelled():
                    raise CanceledError()
                end = first + window if fresh else since + timeout
                if not fresh and now >= end:
                    return None
                self.cond.wait(max(0.0, min(end - now, poll_s)))

    def diagnostics(self) -> dict:
        """/diagnostics values: each sensor's age and last problem, the last view."""
        now, values = self.clock(), {}
        with self.cond:
            for spec in self.specs:
                entry = self.newest.get(spec.topic)
                values[f'sensor {spec.topic}'] = ('silent: nothing received yet' if entry is None
                                                 else f'newest message {now - entry[0]:.2f} s ago')
                if spec.topic in self.problems:
                    values[f'sensor {spec.topic} problem'] = self.problems[spec.topic]
            if self.last_view:
                values['last view'] = self.last_view
        return values


def reading_of(spec: SensorSpec, arrival: float, msg, mount: Callable) -> SensorReading:
    """One message as a SensorReading; ViewError (ScanError, CloudError said) when unusable."""
    return reading_from_msg(spec.topic, spec.kind == SCAN, msg, lambda: mount(spec, msg.header.frame_id), arrival)


def silent(newest: dict, topic: str, since: float) -> bool:
    """Whether the sensor on `topic` has said nothing since `since` in `newest`
    (SensorInputs.wait's answer): no message, or only older ones."""
    arrival, msg = newest.get(topic, (None, None))
    return msg is None or arrival < since


def make_view(inputs: SensorInputs, newest: dict, since: float, mount: Callable, odometry,
              config: ViewConfig) -> tuple[View, dict]:
    """The view of `newest` (SensorInputs.wait's answer) and topic -> its message for the
    sensors in it; ViewError saying every sensor's reason when none contributes."""
    readings, reasons, messages = {}, {}, {}
    for spec in inputs.specs:
        arrival, msg = newest.get(spec.topic, (None, None))
        if silent(newest, spec.topic, since):
            reasons[spec.topic] = ('silent: nothing received' if msg is None else
                                   f'silent: nothing since the request (its newest message arrived '
                                   f'{since - arrival:.2f} s before it)')
            continue
        try:
            readings[spec.topic] = reading_of(spec, arrival, msg, mount)
            messages[spec.topic] = msg
            inputs.problems.pop(spec.topic, None)
        except (ScanError, Mount3DError) as e:     # ViewError, CloudError-as-ViewError, NoMounting
            reasons[spec.topic] = inputs.problems[spec.topic] = f'{type(e).__name__}: {e}'
    try:
        view = merge_view(readings, odometry, config=config, unread=reasons)
    except ViewError as e:
        inputs.last_view = f'no view: {e}'
        raise
    inputs.last_view = view.summary()
    return view, {topic: messages[topic] for topic in view.contributed}


def subscribe(node, specs: tuple, inputs: SensorInputs, primary_scans, guarded, group) -> list:
    """A subscription per sensor (sensor-data QoS) putting into `inputs`; the primary
    laser's scans also go to `primary_scans` (a NewestMessage: the watch, resolve-by-motion)."""
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import LaserScan, PointCloud2

    subs = []
    for spec in specs:
        def on_message(msg, topic=spec.topic, primary=spec.primary):
            inputs.put(topic, msg)
            if primary:
                primary_scans.put(msg)
        on_message.__name__ = f'on_{spec.kind} {spec.topic}'      # its name on /diagnostics' error counts
        subs.append(node.create_subscription(LaserScan if spec.kind == SCAN else PointCloud2, spec.topic,
                                             guarded(on_message), qos_profile_sensor_data, callback_group=group))
    return subs
