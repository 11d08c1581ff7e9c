"""What changes while the server runs, in real processes: maps republished, parameters set
live or wrong at start, reconfiguration, a localizer that is not up when the pose goes
out, a laser that starts late. The server keeps serving and never publishes a pose it
cannot vouch for."""
import json
import subprocess
import time

import numpy as np
import pytest
from geometry_msgs.msg import PoseWithCovarianceStamped
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from nav_msgs.msg import OccupancyGrid
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from ros_helpers import TRUTH, localize, pose_of, start_scan_publisher

from conftest import OFFICE_YAML, assert_pose_near
from global_loc.core.map_io import load_map_yaml, make_map, save_map_yaml
from global_loc.core.transform import Rigid2D, pose_correct
from global_loc.ros.convert import map_to_msg, pose_from_msg
from global_loc.testing.processes import TopicRecorder, isolated_env, reliable, start_client, start_server

pytestmark = pytest.mark.ros


class Operator(TopicRecorder):
    """What an operator does from another process: publish maps, set parameters, drive
    the lifecycle; and what the localizer sees: /initialpose."""

    def __init__(self, env):
        super().__init__(env, {'/initialpose': (PoseWithCovarianceStamped, reliable())}, 'operator')
        self.map_pub = self.node.create_publisher(OccupancyGrid, '/map', reliable(depth=1, latched=True))

    def set(self, **values):
        """Set parameters (bnb__keep_ratio for bnb.keep_ratio); the results, in order."""
        params = [Parameter(name.replace('__', '.'), value=v).to_parameter_msg() for name, v in values.items()]
        return self.call(SetParameters, '/global_loc_server/set_parameters',
                         SetParameters.Request(parameters=params)).results

    def transition(self, transition_id) -> bool:
        return self.call(ChangeState, '/global_loc_server/change_state',
                         ChangeState.Request(transition=Transition(id=transition_id))).success


def client_in_background(env, *args):
    """The --json client started now; call the returned function for (exit code, result)."""
    proc = start_client(env, '--json', *args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def result(timeout=120.0):
        out, err = proc.communicate(timeout=timeout)
        assert out.strip(), err
        return proc.returncode, json.loads(out)
    return result


def shifted_big_office(shift_m: float, size: int = 3000):
    """The office drawn 5 m further along x inside a big empty map: the same walls, another
    place - a scan of the office localizes 5 m off in it (and it takes long to prepare)."""
    office = load_map_yaml(OFFICE_YAML)
    big = np.zeros((size, size), dtype=office.occupancy.dtype)
    dx = int(round(shift_m / office.resolution))
    h, w = office.occupancy.shape
    big[size - h:, dx:dx + w] = office.occupancy       # row 0 is the top: keep the bottom-left origin
    return make_map(big, office.resolution, office.origin, 'big shifted office')


def test_two_maps_in_quick_succession_the_newest_received_is_used(tmp_path):
    """A big map (slow to prepare) then the office at once: the office must win, although
    the big one finishes last; no pose from the big map is ever published."""
    env = isolated_env()
    op = Operator(env)
    server = start_server(env, tmp_path / 'server.log', 'use_map_topic:=true')
    publisher = start_scan_publisher(env, tmp_path / 'pub.log', OFFICE_YAML, TRUTH)
    try:
        small = map_to_msg(load_map_yaml(OFFICE_YAML))
        op.map_pub.publish(map_to_msg(shifted_big_office(5.0)))
        server.wait_for_output('map 2 received')     # the big one is being prepared ...
        op.map_pub.publish(small)                     # ... when the newer, small one arrives
        code, result = localize(env, '--timeout', '20')
        assert code == 0, (result, server.output()[-3000:])
        assert_pose_near(pose_of(result), TRUTH)
        time.sleep(0.5)
        for msg in op.messages['/initialpose']:
            assert pose_correct(pose_from_msg(msg.pose.pose), TRUTH), pose_from_msg(msg.pose.pose)
        assert 'map 2 dropped: map 3 arrived while it was being prepared' in server.output()
    finally:
        publisher.stop()
        op.close()
        assert server.stop() == 0


def test_a_goal_whose_map_is_replaced_mid_search_publishes_nothing(tmp_path):
    env = isolated_env()
    op = Operator(env)
    op.map_pub.publish(map_to_msg(load_map_yaml(OFFICE_YAML)))
    server = start_server(env, tmp_path / 'server.log', 'use_map_topic:=true')
    publisher = start_scan_publisher(env, tmp_path / 'pub.log', OFFICE_YAML, TRUTH)
    try:
        server.wait_for_output('map 2 in use')
        client = client_in_background(env, '--method', 'template_ccoeff', '--angle-step', '2', '--timeout', '10')
        server.wait_for_output('matching a scan', timeout=20)
        op.map_pub.publish(map_to_msg(shifted_big_office(5.0, size=800)))
        code, result = client()
        assert result['outcome'] == 'no_map' and 'not published: a newer map arrived' in result['message'], result
        time.sleep(0.5)
        assert op.messages['/initialpose'] == []
    finally:
        publisher.stop()
        op.close()
        assert server.stop() == 0


def test_a_live_parameter_applies_to_the_next_goal_and_a_refused_one_says_why(tmp_path):
    env = isolated_env()
    op = Operator(env)
    server = start_server(env, tmp_path / 'server.log')
    try:
        code, result = localize(env)               # no scans: the default 5 s timeout
        assert result['outcome'] == 'no_scan' and 'within 5.0 s' in result['message'], result
        assert op.set(scan_timeout_s=0.5)[0].successful
        code, result = localize(env)
        assert result['outcome'] == 'no_scan' and 'within 0.5 s' in result['message'], result
        refused = op.set(method='no_such_matcher')[0]
        assert not refused.successful and 'unknown method' in refused.reason, refused
        refused = op.set(method='features_sift')[0]      # known, but not prepared with the map
        assert not refused.successful and 'features_sift is not prepared' in refused.reason, refused
        assert op.set(method='template_sqdiff')[0].successful      # in the default methods
        refused = op.set(bnb__keep_ratio=5.0)[0]
        assert not refused.successful and 'keep_ratio' in refused.reason + str(refused), refused
        deferred = op.set(bnb__max_nodes=50)[0]
        assert not deferred.successful and deferred.reason.startswith('bnb.max_nodes: read at configure, not live')
        assert 'Traceback' not in server.output()
    finally:
        op.close()
        assert server.stop() == 0


def test_a_changed_map_yaml_loads_on_reconfigure(tmp_path):
    square = tmp_path / 'square.yaml'
    save_map_yaml(make_map(np.pad(np.zeros((40, 60), dtype=np.uint8), 1, constant_values=100), 0.05, Rigid2D(),
                           'square'), square)
    env = isolated_env()
    op = Operator(env)
    server = start_server(env, tmp_path / 'server.log')
    try:
        assert 'office' in server.output()
        refused = op.set(map_yaml=str(square))[0]
        assert not refused.successful and 'clean up the node, set it, configure again' in refused.reason
        assert op.transition(Transition.TRANSITION_DEACTIVATE) and op.transition(Transition.TRANSITION_CLEANUP)
        assert op.set(map_yaml=str(square))[0].successful
        assert op.transition(Transition.TRANSITION_CONFIGURE)
        server.wait_for_output('62 x 42 cells')
    finally:
        op.close()
        assert server.stop() == 0


@pytest.mark.parametrize('bad', ['bnb.keep_ratio:=1.5', 'bnb.levels:=9', 'method:=no_such_matcher'])
def test_an_invalid_parameter_fails_configure_then_a_corrected_one_brings_it_up(tmp_path, bad):
    env = isolated_env()
    op = Operator(env)
    server = start_server(env, tmp_path / 'server.log', bad, ready_line='configure failed')
    publisher = start_scan_publisher(env, tmp_path / 'pub.log', OFFICE_YAML, TRUTH)
    try:
        name = bad.split(':=')[0]
        assert name in server.output() and 'Traceback' not in server.output(), server.output()
        code, result = localize(env, '--timeout', '2')
        assert result['outcome'] == 'not_active' and name in result['message'], result
        default = {'bnb.keep_ratio': 0.9, 'bnb.levels': 7, 'method': 'bnb'}[name]
        assert op.set(**{name.replace('.', '__'): default})[0].successful
        assert op.transition(Transition.TRANSITION_CONFIGURE) and op.transition(Transition.TRANSITION_ACTIVATE)
        code, result = localize(env, '--timeout', '10')
        assert code == 0, result
        assert_pose_near(pose_of(result), TRUTH)
    finally:
        publisher.stop()
        op.close()
        assert server.stop() == 0


def test_auto_relocalize_retries_when_the_localizer_missed_the_pose(tmp_path):
    """No localizer is up: the one /initialpose goes nowhere. After relocalize.settle_s the
    server says so and publishes again, within its guards."""
    env = isolated_env()
    op = Operator(env)
    server = start_server(env, tmp_path / 'server.log', 'auto_relocalize:=true', 'relocalize.start_delay_s:=0.5',
                          'relocalize.settle_s:=2.0', 'relocalize.min_interval_s:=1.0', 'relocalize.max_attempts:=5')
    publisher = start_scan_publisher(env, tmp_path / 'pub.log', OFFICE_YAML, TRUTH)
    try:
        poses = op.wait_for('/initialpose', 2, timeout=40.0)
        assert len(poses) >= 2, server.output()[-3000:]
        for msg in poses:
            assert pose_correct(pose_from_msg(msg.pose.pose), TRUTH)
        assert 'took no pose' in server.output() or len(poses) >= 2
    finally:
        publisher.stop()
        op.close()
        assert server.stop() == 0


def test_auto_relocalize_waits_for_a_late_laser_instead_of_giving_up(tmp_path):
    """Scans start 8 s after activation; with max_attempts 1 and 0.5 s scan timeouts the old
    server had spent its attempts on 'no scan' and reported lost for good."""
    env = isolated_env()
    op = Operator(env)
    server = start_server(env, tmp_path / 'server.log', 'auto_relocalize:=true', 'relocalize.start_delay_s:=0.2',
                          'relocalize.min_interval_s:=0.5', 'relocalize.max_attempts:=1', 'scan_timeout_s:=0.5')
    try:
        time.sleep(8.0)
        assert op.messages['/initialpose'] == []
        publisher = start_scan_publisher(env, tmp_path / 'pub.log', OFFICE_YAML, TRUTH)
        try:
            poses = op.wait_for('/initialpose', 1, timeout=30.0)
            assert poses, server.output()[-3000:]
            assert_pose_near(pose_from_msg(poses[0].pose.pose), TRUTH)
        finally:
            publisher.stop()
    finally:
        op.close()
        assert server.stop() == 0
