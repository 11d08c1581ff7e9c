"""/tf_static without tf2_ros (which PyPI does not carry): a URDF's fixed joints
published the way robot_state_publisher publishes them (the simulator's sensors), and a
reader for the server where tf2_ros is not importable - every static transform received,
a sensor's frame composed onto base_frame through them (core/frames.py), as tf2's buffer
would. Both need tf2_msgs (built from vendor/tf2_msgs where PyPI lacks it); without it
neither exists, and the caller says so."""
from __future__ import annotations

import threading
from typing import Callable, Optional

import numpy as np
from geometry_msgs.msg import TransformStamped
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from ..core.frames import compose, transform_matrix
from ..core.mount3d import Mount3D
from ..core.transform import quaternion_of_rpy
from ..io.messages import transform_from_msg

TF_STATIC = '/tf_static'
PUBLISHER_DEPTH = 1        # robot_state_publisher's: one latched message with every joint
LISTENER_DEPTH = 100       # tf2_ros' static listener's: every static broadcaster's latched message


def static_qos(depth: int) -> QoSProfile:
    """/tf_static's QoS: reliable and transient local, so a late subscriber still gets it."""
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def tf_message_type():
    """tf2_msgs/msg/TFMessage, or None where no tf2_msgs is installed."""
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:
        return None
    return TFMessage


def joint_transforms(joints, stamp) -> list:
    """io.urdf.FixedJoint's as TransformStamped messages (parent -> child), stamped `stamp`."""
    msgs = []
    for joint in joints:
        t = TransformStamped()
        t.header.stamp, t.header.frame_id, t.child_frame_id = stamp, joint.parent, joint.child
        o = joint.origin
        t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = (float(o.x), float(o.y),
                                                                                           float(o.z))
        r = t.transform.rotation
        r.x, r.y, r.z, r.w = quaternion_of_rpy(o.roll, o.pitch, o.yaw)
        msgs.append(t)
    return msgs


def publish_static_transforms(node, joints):
    """One latched /tf_static message of `joints` (robot_state_publisher's QoS); the
    publisher, kept by the caller, or None without tf2_msgs."""
    message_type = tf_message_type()
    if message_type is None:
        return None
    publisher = node.create_publisher(message_type, TF_STATIC, static_qos(PUBLISHER_DEPTH))
    publisher.publish(message_type(transforms=joint_transforms(joints, node.get_clock().now().to_msg())))
    return publisher


class StaticTransforms:
    """Every transform received on /tf_static, each child frame's newest (as tf2 keeps
    them); a lookup reads what has arrived and never waits for more."""

    def __init__(self):
        self._lock = threading.Lock()      # guards _parents (the subscription's thread writes, requests read)
        self._parents: dict = {}           # child frame -> (parent frame, 4x4 parent_T_child)

    def add(self, msg) -> list:
        """A TFMessage's transforms; the 'parent -> child' of those that are new or changed.
        One that is not finite (or has a zero quaternion) is skipped."""
        changed = []
        for t in msg.transforms:
            child, parent, translation, quaternion = transform_from_msg(t)
            try:
                matrix = transform_matrix(translation, quaternion)
            except ValueError:
                continue
            with self._lock:
                known = self._parents.get(child)
                self._parents[child] = (parent, matrix)
            if known is None or known[0] != parent or not np.allclose(known[1], matrix):
                changed.append(f'{parent} -> {child}')
        return changed

    def lookup(self, base: str, frame: str) -> Optional[tuple]:
        """(`frame` on `base` as a Mount3D, the frames composed 'base -> ... -> frame'), or None
        when the transforms received do not link them (or `frame` is `base` itself: no
        transform says anything about it, the parameters do)."""
        with self._lock:
            parents = dict(self._parents)
        chain = compose(parents, base, frame)
        if chain is None or not chain.composed:
            return None
        return Mount3D.from_matrix(chain.base_T_frame), ' -> '.join(chain.frames)


def subscribe_static_transforms(node, guarded: Callable = lambda f: f) -> Optional[StaticTransforms]:
    """A StaticTransforms fed by a /tf_static subscription of `node` (tf2's static listener
    QoS), or None without tf2_msgs."""
    message_type = tf_message_type()
    if message_type is None:
        return None
    transforms = StaticTransforms()

    def on_tf_static(msg) -> None:
        changed = transforms.add(msg)
        if changed:       # when the mountings became known: a request before it used the parameters
            node.get_logger().info(f'/tf_static: {", ".join(changed)} received')
    transforms.subscription = node.create_subscription(message_type, TF_STATIC, guarded(on_tf_static),
                                                       static_qos(LISTENER_DEPTH))
    return transforms
