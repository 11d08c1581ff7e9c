"""The action server, the client and /initialpose in separate processes over real DDS."""
import math
import os
import re
import sys
import time

import pytest

from conftest import OFFICE_YAML
from global_loc.processes import Process, TopicRecorder, isolated_env, reliable, run_client, start_server

TEST_DIR = os.path.dirname(os.path.abspath(__file__))

TRUTH = (3.0, 4.0, 0.7)     # a place every matcher but features gets right; see test_matchers


def parse_pose(stdout: str):
    m = re.search(r'pose:\s+x=(\S+) y=(\S+) yaw=(\S+) deg', stdout)
    assert m, stdout
    return float(m.group(1)), float(m.group(2)), math.radians(float(m.group(3)))


def assert_close(pose, truth):
    assert math.hypot(pose[0] - truth[0], pose[1] - truth[1]) < 0.2, (pose, truth)
    assert abs((pose[2] - truth[2] + math.pi) % (2 * math.pi) - math.pi) < math.radians(5), (pose, truth)


def start_scan_publisher(env, log_path, map_yaml, pose, rate=5.0) -> Process:
    """test/scan_publisher.py: scans ray-cast at `pose` (numpy, not the simulator)."""
    return Process([sys.executable, os.path.join(TEST_DIR, 'scan_publisher.py'), map_yaml,
                    *map(str, pose), str(rate)], env, log_path)


def initialpose_listener(env) -> TopicRecorder:
    from geometry_msgs.msg import PoseWithCovarianceStamped
    return TopicRecorder(env, {'/initialpose': (PoseWithCovarianceStamped, reliable())})


@pytest.fixture(scope='module')
def system(tmp_path_factory):
    """Server + scan publisher at TRUTH + an /initialpose listener, on a private domain."""
    logs = tmp_path_factory.mktemp('ros')
    env = isolated_env()
    listener = initialpose_listener(env)
    server = start_server(env, logs / 'server.log', 'scan_timeout_s:=5.0')
    publisher = start_scan_publisher(env, logs / 'publisher.log', OFFICE_YAML, TRUTH)
    assert listener.wait_for_publisher('/initialpose')
    yield env, server, listener
    publisher.stop()
    listener.close()
    assert server.stop() == 0, f'server did not exit cleanly on SIGTERM:\n{server.output()}'


def test_client_localizes_and_initialpose_carries_the_same_pose(system):
    env, server, listener = system
    before = len(listener.messages['/initialpose'])
    out = run_client(env, '--timeout', '10')
    assert out.returncode == 0, out.stdout + out.stderr
    assert 'succeeded: localized' in out.stdout
    assert 'waiting_for_scan' in out.stdout and 'matching' in out.stdout      # feedback arrived
    pose = parse_pose(out.stdout)
    assert_close(pose, TRUTH)
    msgs = listener.wait_for('/initialpose', before + 1)
    assert len(msgs) == before + 1, 'nothing on /initialpose'
    msg = msgs[-1]
    assert msg.header.frame_id == 'map'
    q = msg.pose.pose.orientation
    assert math.isclose(q.x ** 2 + q.y ** 2 + q.z ** 2 + q.w ** 2, 1.0, rel_tol=1e-9)
    published = (msg.pose.pose.position.x, msg.pose.pose.position.y, 2 * math.atan2(q.z, q.w))
    assert_close(published, pose)
    assert all(math.isfinite(c) for c in msg.pose.covariance)
    assert msg.pose.covariance[0] > 0 and msg.pose.covariance[7] > 0 and msg.pose.covariance[35] > 0


def test_no_publish_goal_leaves_initialpose_alone(system):
    env, server, listener = system
    before = len(listener.messages['/initialpose'])
    out = run_client(env, '--no-publish')
    assert out.returncode == 0, out.stdout + out.stderr
    time.sleep(1.0)
    assert len(listener.messages['/initialpose']) == before


def test_unknown_method_aborts_and_the_server_keeps_serving(system):
    env, server, _ = system
    out = run_client(env, '--method', 'magic')
    assert out.returncode == 1
    assert "aborted: unknown method 'magic'" in out.stdout
    assert run_client(env).returncode == 0


def test_cancel_mid_search_ends_the_goal_quickly_and_the_server_keeps_serving(system):
    env, server, _ = system
    t0 = time.monotonic()
    # The thesis matcher at Δα = 0.5 deg: 720 rotations, far longer than the 1.5 s before the cancel.
    out = run_client(env, '--method', 'template_ccoeff', '--angle-step', '0.5', '--cancel-after', '1.5')
    elapsed = time.monotonic() - t0
    assert 'canceled: canceled' in out.stdout, out.stdout + out.stderr
    assert out.returncode == 1
    assert elapsed < 15, f'cancel took the client {elapsed:.1f} s in all'
    assert run_client(env).returncode == 0


def test_goal_while_busy_is_aborted_with_a_reason(system):
    env, server, _ = system
    import subprocess
    from global_loc.processes import ros2
    started = server.output().count('matching a scan')
    slow = subprocess.Popen([ros2(), 'run', 'global_loc', 'test_global_loc', '--method', 'template_ccoeff',
                             '--angle-step', '0.5',
                             '--cancel-after', '8'], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 20
        while server.output().count('matching a scan') == started and time.monotonic() < deadline:
            time.sleep(0.1)
        busy = run_client(env)
        assert busy.returncode == 1
        assert 'aborted: busy: another goal is running' in busy.stdout
    finally:
        slow_out, _ = slow.communicate(timeout=60)
    assert 'succeeded: localized' in slow_out or 'canceled: canceled' in slow_out, slow_out   # the first goal ran on


def test_no_scan_within_timeout_aborts_then_next_goal_works(tmp_path):
    env = isolated_env()
    server = start_server(env, tmp_path / 'server.log')
    try:
        out = run_client(env, '--timeout', '1.0')
        assert out.returncode == 1
        assert 'aborted: no scan on /scan within 1.0 s' in out.stdout
        publisher = start_scan_publisher(env, tmp_path / 'pub.log', OFFICE_YAML, TRUTH)
        try:
            out = run_client(env, '--timeout', '10')
            assert out.returncode == 0, out.stdout
        finally:
            publisher.stop()
    finally:
        assert server.stop() == 0


def test_missing_map_file_server_starts_and_aborts_goals_with_the_reason(tmp_path):
    env = isolated_env()
    server = start_server(env, tmp_path / 'server.log', f'map_yaml:={tmp_path}/nothere.yaml')
    try:
        assert 'map not loaded' in server.output()
        for _ in range(2):    # and it keeps answering
            out = run_client(env)
            assert out.returncode == 1
            assert 'aborted: map not loaded:' in out.stdout and 'nothere.yaml: map YAML not found' in out.stdout
    finally:
        assert server.stop() == 0


def test_client_without_server_says_so(tmp_path):
    env = isolated_env()
    out = run_client(env, '--server-timeout', '1')
    assert out.returncode == 2
    assert 'no global_loc server answered' in out.stderr


def test_map_from_occupancy_grid_topic(tmp_path):
    """use_map_topic: the map arrives as a transient-local OccupancyGrid, like nav2's map_server."""
    import numpy as np
    import rclpy
    from nav_msgs.msg import OccupancyGrid
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from global_loc.map_io import load_map_yaml
    env = isolated_env()
    m = load_map_yaml(OFFICE_YAML)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(env['ROS_DOMAIN_ID']))
    node = rclpy.create_node('test_map_server', context=context)
    pub = node.create_publisher(OccupancyGrid, '/map', QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                                                   durability=DurabilityPolicy.TRANSIENT_LOCAL))
    msg = OccupancyGrid()
    msg.header.frame_id = 'map'
    msg.info.resolution, msg.info.width, msg.info.height = m.resolution, m.width, m.height
    msg.info.origin.position.x, msg.info.origin.position.y = m.origin.x, m.origin.y
    msg.info.origin.orientation.w = 1.0
    msg.data = np.flipud(m.occupancy).astype(np.int8).ravel().tolist()
    pub.publish(msg)     # before the server exists: transient local delivers it late
    server = start_server(env, tmp_path / 'server.log', 'use_map_topic:=true')
    publisher = start_scan_publisher(env, tmp_path / 'pub.log', OFFICE_YAML, TRUTH)
    try:
        server.wait_for_output('map OccupancyGrid on map: 520 x 360 cells')
        out = run_client(env, '--timeout', '10')
        assert out.returncode == 0, out.stdout + server.output()
        assert_close(parse_pose(out.stdout), TRUTH)
    finally:
        publisher.stop()
        assert server.stop() == 0
        node.destroy_node()
        context.try_shutdown()


def test_ambiguous_place_publishes_nothing_unless_asked(tmp_path):
    """A four-fold symmetric room: the result says ambiguous, lists the hypotheses, and
    /initialpose stays silent unless the goal asks to publish the best anyway."""
    from test_bnb import symmetric_room

    from global_loc.map_io import save_map_yaml
    save_map_yaml(symmetric_room(), tmp_path / 'square.yaml')
    env = isolated_env()
    listener = initialpose_listener(env)
    server = start_server(env, tmp_path / 'server.log', f'map_yaml:={tmp_path / "square.yaml"}')
    publisher = start_scan_publisher(env, tmp_path / 'pub.log', str(tmp_path / 'square.yaml'), (2.0, 1.4, 0.4))
    assert listener.wait_for_publisher('/initialpose')
    try:
        out = run_client(env, '--timeout', '10')
        assert out.returncode == 1, out.stdout
        assert 'aborted: ambiguous' in out.stdout and 'hypothesis 4:' in out.stdout
        time.sleep(1.0)
        assert listener.messages['/initialpose'] == []
        out = run_client(env, '--timeout', '10', '--publish-if-ambiguous')
        assert out.returncode == 1 and 'aborted: ambiguous' in out.stdout
        assert len(listener.wait_for('/initialpose', 1)) == 1
    finally:
        publisher.stop()
        listener.close()
        assert server.stop() == 0
