"""/tf_static without tf2_ros: the simulator publishes its sensors' mountings from its URDF
as robot_state_publisher would, and the server composes base_link <- a sensor's frame from
the static transforms it received (ros/tf_static.py), tf first, then the parameters
(ros/sensors.py SensorMounts) - so the simulator's robot localizes with no mounting given."""
import importlib.util
import json
import os

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
from ros_helpers import TRUTH, localize, pose_of

from conftest import OFFICE_YAML, assert_pose_near
from global_loc.core.mount3d import Mount3D
from global_loc.io.urdf import FixedJoint
from global_loc.ros.sensors import CLOUD, SCAN, NoMounting, SensorMounts, SensorSpec
from global_loc.ros.tf_static import StaticTransforms, joint_transforms, static_qos, tf_message_type
from global_loc.sim import robot
from global_loc.testing.processes import TopicRecorder, isolated_env, start_server, start_sim

pytestmark = pytest.mark.ros

TFMessage = tf_message_type()
# `ros2 topic info -v /tf_static` on a Jazzy install: the hash of upstream's TFMessage
JAZZY_TF_MESSAGE_HASH = 'RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087'
MAST = Mount3D(0.1, 0.0, 0.3, 0.0, 0.0, 1.5707963267948966)
ON_MAST = Mount3D(0.05, 0.0, 0.2, 3.141592653589793, 0.0, 0.0)     # upside down on the mast
TIGHT_M, TIGHT_DEG = 0.1, 3.0


def static_message(*joints) -> 'TFMessage':
    return TFMessage(transforms=joint_transforms([FixedJoint(f'{j[1]}_joint', *j) for j in joints], Time()))


def assert_same_mount(a: Mount3D, b: Mount3D) -> None:
    assert np.allclose(a.matrix(), b.matrix(), atol=1e-9), (a, b)


class StubNode:
    """What SensorMounts asks of a node: a logger and one subscription, kept to be fed by hand."""

    def __init__(self):
        self.lines, self.subscriptions = [], []

    def get_logger(self):
        return self

    def info(self, line: str) -> None:
        self.lines.append(line)

    def create_subscription(self, msg_type, topic, callback, qos):
        self.subscriptions.append((msg_type, topic, callback, qos))
        return object()


@pytest.fixture
def mounts():
    if importlib.util.find_spec('tf2_ros') is not None:
        pytest.skip('tf2_ros is installed: the server uses it, not the /tf_static reader')
    node = StubNode()
    m = SensorMounts(node)
    m.configure({'base_frame': 'base_link', 'laser_x': 0.16, 'laser_y': 0.0, 'laser_yaw': 0.0, 'laser_roll': 0.0})
    return m, node


def test_the_reader_subscribes_as_tf2s_static_listener(mounts):
    _, node = mounts
    [(msg_type, topic, _, qos)] = node.subscriptions
    assert msg_type is TFMessage and topic == '/tf_static' and qos.depth == 100
    assert qos.durability == DurabilityPolicy.TRANSIENT_LOCAL and qos.reliability == ReliabilityPolicy.RELIABLE


def test_a_mounting_comes_from_tf_static_once_it_arrives_and_from_the_parameters_before(mounts):
    mounts, node = mounts
    deliver = node.subscriptions[0][2]
    scan = SensorSpec('/scan', SCAN, None, True)
    lidar_mount = Mount3D(0.0, 0.0, 0.5)
    points = SensorSpec('/points', CLOUD, lidar_mount)
    assert mounts.mount(scan, 'laser') == Mount3D(0.16, 0.0, 0.0)          # nothing on /tf_static yet
    deliver(static_message(('base_link', 'mast', MAST)))
    deliver(static_message(('mast', 'laser', ON_MAST)))                     # a second broadcaster
    assert '/tf_static: mast -> laser received' in node.lines
    assert_same_mount(mounts.mount(scan, 'laser'), Mount3D.from_matrix(MAST.matrix() @ ON_MAST.matrix()))
    mounts.mount(scan, 'laser')
    said = [line for line in node.lines if 'mounting from /tf_static' in line]
    assert len(said) == 1 and said[0].startswith('/scan: mounting from /tf_static (base_link -> mast -> laser)')
    assert 'laser_x/laser_y/laser_yaw/laser_roll say x=0.160' in said[0] and 'tf comes first' in said[0]
    # the lidar: its parameter until /tf_static has its frame; then tf, agreeing, nothing more said
    assert mounts.mount(points, 'lidar') == lidar_mount
    deliver(static_message(('base_link', 'lidar', lidar_mount)))
    assert_same_mount(mounts.mount(points, 'lidar'), lidar_mount)
    assert [line for line in node.lines if line.startswith('/points: mounting from /tf_static (base_link -> lidar)')
            and 'tf comes first' not in line]
    # a message stamped in base_link itself is the parameters' to place; an unknown frame, nobody's
    assert mounts.mount(scan, 'base_link') == Mount3D(0.16, 0.0, 0.0)
    with pytest.raises(NoMounting, match='no tf base_link <- camera and no parameter sensors.camera.mount'):
        mounts.mount(SensorSpec('/camera', CLOUD), 'camera')


def test_a_transform_that_cannot_be_read_is_skipped():
    transforms = StaticTransforms()
    bad = static_message(('base_link', 'laser', Mount3D(0.2, 0.0, 0.3)))
    bad.transforms[0].transform.rotation.w = 0.0           # a zero quaternion
    assert transforms.add(bad) == [] and transforms.lookup('base_link', 'laser') is None
    assert transforms.add(static_message(('/base_link', 'laser', Mount3D(0.2, 0.0, 0.3)))) == ['base_link -> laser']
    assert transforms.lookup('base_link', 'laser')[0] == Mount3D(0.2, 0.0, 0.3)      # tf2's names: no slash


def test_the_tf2_msgs_here_is_jazzys_tf_message():
    from ament_index_python.packages import get_package_share_directory
    with open(os.path.join(get_package_share_directory('tf2_msgs'), 'msg', 'TFMessage.json')) as f:
        hashes = json.load(f)['type_hashes']
    assert {h['type_name']: h['hash_string'] for h in hashes}['tf2_msgs/msg/TFMessage'] == JAZZY_TF_MESSAGE_HASH


def test_the_simulator_publishes_its_sensors_mountings_from_its_urdf(tmp_path):
    env = isolated_env()
    sim = start_sim(env, tmp_path / 'sim.log', 'rear_laser:=true', 'lidar3d:=true')
    recorder = TopicRecorder(env, {'/tf_static': (TFMessage, static_qos(100))})    # joins late: it is latched
    try:
        [msg] = recorder.wait_for('/tf_static', 1)
        [info] = recorder.node.get_publishers_info_by_topic('/tf_static')
        assert info.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
        assert info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        assert sorted(t.child_frame_id for t in msg.transforms) == ['laser', 'laser_rear', 'lidar']
        transforms = StaticTransforms()
        transforms.add(msg)
        for frame, mount in ((robot.LASER_FRAME, robot.FRONT_LASER_MOUNT),
                             (robot.REAR_LASER_FRAME, robot.REAR_LASER_MOUNT), (robot.LIDAR_FRAME, robot.LIDAR_MOUNT)):
            assert_same_mount(transforms.lookup(robot.BASE_FRAME, frame)[0], mount)
        assert 'mountings on /tf_static (base_link -> laser, laser_rear, lidar, from the URDF)' in sim.output()
    finally:
        recorder.close()
        assert sim.stop() == 0, sim.output()


def assert_base_pose_from_tf_static(env, server, sim, received: str, mounting: str):
    """Once the server logs `received`, a goal answers base_link's true pose, and the log says
    the sensor's mounting came from /tf_static; both processes then stop."""
    try:
        # discovery can take 2 s to match the two; a request before it finds no mounting from tf
        server.wait_for_output(f'/tf_static: {received} received', timeout=10)
        code, result = localize(env, '--timeout', '20', '--no-publish')
        assert code == 0 and result['outcome'] == 'localized', result
        assert_pose_near(pose_of(result), TRUTH, TIGHT_M, TIGHT_DEG)
        assert mounting in server.output()
    finally:
        sim.stop()
        assert server.stop() == 0, server.output()


def test_the_simulated_lidar_alone_localizes_with_no_mounting_given(tmp_path):
    env = isolated_env()
    sim = start_sim(env, tmp_path / 'sim.log', f'map_yaml:={OFFICE_YAML}', 'lidar3d:=true', f'x:={TRUTH.x}',
                    f'y:={TRUTH.y}', f'yaw:={TRUTH.yaw}')
    server = start_server(env, tmp_path / 'server.log', f'map_yaml:={OFFICE_YAML}', 'scan_topics:=[]',
                          'cloud_topics:=[/points]')
    assert_base_pose_from_tf_static(env, server, sim, 'base_link -> laser, base_link -> lidar',
                                    '/points: mounting from /tf_static (base_link -> lidar): x=0.000 y=0.000 z=0.500')


def test_the_front_laser_gives_the_bases_pose_without_laser_x_from_a_late_tf_static(tmp_path):
    """The server starts first, so /tf_static arrives after it configured; the answer is
    base_link's pose, not the laser's 0.16 m ahead of it."""
    env = isolated_env()
    server = start_server(env, tmp_path / 'server.log', f'map_yaml:={OFFICE_YAML}')
    sim = start_sim(env, tmp_path / 'sim.log', f'x:={TRUTH.x}', f'y:={TRUTH.y}', f'yaw:={TRUTH.yaw}')
    assert_base_pose_from_tf_static(env, server, sim, 'base_link -> laser',
                                    '/scan: mounting from /tf_static (base_link -> laser): x=0.160 y=0.000 z=0.300')
