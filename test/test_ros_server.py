"""The action server, the client and /initialpose in separate processes over real DDS.
The client's --json result (outcome, pose, ...) is what the tests read."""
import json
import subprocess
import time

import pytest
from geometry_msgs.msg import PoseWithCovarianceStamped
from ros_helpers import TRUTH, ApiLocalizer, localize, pose_of, start_scan_publisher

from conftest import OFFICE_YAML, assert_pose_near, symmetric_room
from global_loc.core.outcome import Outcome
from global_loc.core.transform import Rigid2D
from global_loc.ros.convert import pose_from_msg
from global_loc.testing.processes import (
    TopicRecorder,
    isolated_env,
    reliable,
    run_client,
    start_client,
    start_server,
)

pytestmark = pytest.mark.ros   # real ROS processes (the compat run has no ROS: -m 'not ros')


def initialpose_listener(env) -> TopicRecorder:
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


def test_outcome_constants_of_the_action_are_the_core_outcomes():
    from global_loc_interfaces.action import Localize
    for outcome in Outcome:
        assert getattr(Localize.Result, outcome.name) == outcome.value, outcome


def test_client_localizes_and_initialpose_carries_the_same_pose(system):
    env, server, listener = system
    before = len(listener.messages['/initialpose'])
    code, result = localize(env, '--timeout', '10')
    assert code == 0 and result['outcome'] == 'localized' and result['status'] == 'succeeded', result
    assert_pose_near(pose_of(result), TRUTH)
    cov = result['covariance']
    assert cov[0][0] > 0 and cov[1][1] > 0 and cov[2][2] > 0
    assert result['confidence'] >= 0.5 and len(result['hypotheses']) >= 1
    msgs = listener.wait_for('/initialpose', before + 1)
    assert len(msgs) == before + 1, 'nothing on /initialpose'
    msg = msgs[-1]
    assert msg.header.frame_id == 'map'
    q = msg.pose.pose.orientation
    assert abs(q.x ** 2 + q.y ** 2 + q.z ** 2 + q.w ** 2 - 1.0) < 1e-9
    assert_pose_near(pose_from_msg(msg.pose.pose), pose_of(result), 1e-3, 0.01)
    assert all(c == c for c in msg.pose.covariance)     # finite: no NaN


def test_human_output_shows_feedback_pose_and_status(system):
    env, _, _ = system
    out = run_client(env, '--timeout', '10', '--no-publish')
    assert out.returncode == 0, out.stdout + out.stderr
    assert 'waiting_for_scan' in out.stdout and 'matching' in out.stdout      # feedback arrived
    assert 'pose:       x=' in out.stdout and 'succeeded: localized' in out.stdout


def test_no_publish_goal_leaves_initialpose_alone(system):
    env, server, listener = system
    before = len(listener.messages['/initialpose'])
    code, result = localize(env, '--no-publish')
    assert code == 0 and result['outcome'] == 'localized', result
    time.sleep(1.0)
    assert len(listener.messages['/initialpose']) == before


def test_unknown_method_is_a_bad_goal_and_the_server_keeps_serving(system):
    env, server, _ = system
    code, result = localize(env, '--method', 'magic')
    assert code == 1 and result['outcome'] == 'bad_goal' and result['status'] == 'aborted'
    assert "unknown method 'magic'" in result['message']
    code, result = localize(env, '--method', 'template_ccoeff', '--angle-step', '-5')
    assert code == 1 and result['outcome'] == 'bad_goal'
    assert 'angle step must be in [0.1, 180] degrees' in result['message']
    assert localize(env)[0] == 0


def test_cancel_mid_search_ends_the_goal_quickly_and_the_server_keeps_serving(system):
    env, server, _ = system
    t0 = time.monotonic()
    # The thesis matcher at Δα = 0.5 deg: 720 rotations, far longer than the 1.5 s before the cancel.
    code, result = localize(env, '--method', 'template_ccoeff', '--angle-step', '0.5', '--cancel-after', '1.5')
    elapsed = time.monotonic() - t0
    assert code == 1 and result['outcome'] == 'canceled' and result['status'] == 'canceled', result
    assert elapsed < 15, f'cancel took the client {elapsed:.1f} s in all'
    assert localize(env)[0] == 0


def test_goal_while_busy_is_aborted_with_a_reason(system):
    """The second goal comes from a client connected before the first starts: a client
    started then needs seconds to send it (measured: 4.5 s on a fresh CI clone), longer
    than the first search may run (3.9 s there), and the server was free again."""
    env, server, _ = system
    second = ApiLocalizer(env)
    try:
        assert second.api.wait_until_active(30.0)
        started = server.output().count('matching a scan')
        slow = start_client(env, '--json', '--method', 'template_ccoeff', '--angle-step', '0.5', '--cancel-after',
                            '8', stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            deadline = time.monotonic() + 20
            while server.output().count('matching a scan') == started and time.monotonic() < deadline:
                time.sleep(0.05)
            busy_lines = server.output().count('refused: busy')
            result = second.api.localize()
            assert result.status == 'aborted' and result.outcome == Outcome.BUSY, result
            assert result.message.startswith('busy: another localization is running')
            assert server.output().count('refused: busy') == busy_lines + 1       # logged once, not once per retry
        finally:
            slow_out, _ = slow.communicate(timeout=60)
    finally:
        second.close()
    # the first goal ran on (to its end, its cancel, or its max_search_s)
    assert json.loads(slow_out)['outcome'] in ('localized', 'canceled', 'search_incomplete'), slow_out


def test_no_scan_within_timeout_aborts_then_next_goal_works(tmp_path):
    env = isolated_env()
    server = start_server(env, tmp_path / 'server.log')
    try:
        code, result = localize(env, '--timeout', '1.0')
        assert code == 1 and result['outcome'] == 'no_scan'
        assert result['message'] == 'no scan on /scan within 1.0 s'
        publisher = start_scan_publisher(env, tmp_path / 'pub.log', OFFICE_YAML, TRUTH)
        try:
            assert localize(env, '--timeout', '10')[0] == 0
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
            code, result = localize(env)
            assert code == 1 and result['outcome'] == 'no_map'
            assert result['message'].startswith('map not loaded:') and 'nothere.yaml: map YAML not found' in \
                result['message']
    finally:
        assert server.stop() == 0


def test_client_without_server_says_so(tmp_path):
    env = isolated_env()
    out = run_client(env, '--server-timeout', '1')
    assert out.returncode == 3
    assert 'no global_loc server answered' in out.stderr


def test_bnb_options_are_server_parameters(tmp_path):
    """bnb.max_nodes:=50 stops every search at its budget: never a success, and it says so."""
    env = isolated_env()
    server = start_server(env, tmp_path / 'server.log', 'bnb.max_nodes:=50')
    publisher = start_scan_publisher(env, tmp_path / 'pub.log', OFFICE_YAML, TRUTH)
    try:
        code, result = localize(env, '--timeout', '10')
        assert code == 1 and result['outcome'] == 'search_incomplete', result
        assert 'stopped after 50 node expansions' in result['message']
    finally:
        publisher.stop()
        assert server.stop() == 0


def office_grid_msg(origin_x=None):
    from global_loc.core.map_io import load_map_yaml
    from global_loc.ros.convert import map_to_msg
    msg = map_to_msg(load_map_yaml(OFFICE_YAML))
    if origin_x is not None:
        msg.info.origin.position.x = origin_x
    return msg


def test_map_from_occupancy_grid_topic(tmp_path):
    """use_map_topic: the map arrives as a transient-local OccupancyGrid, like nav2's map_server."""
    import rclpy
    from nav_msgs.msg import OccupancyGrid
    env = isolated_env()
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(env['ROS_DOMAIN_ID']))
    node = rclpy.create_node('test_map_server', context=context)
    pub = node.create_publisher(OccupancyGrid, '/map', reliable(depth=1, latched=True))
    # a NaN origin is refused with the reason (once it was accepted and NaN poses published)
    pub.publish(office_grid_msg(origin_x=float('nan')))   # before the server exists: transient local
    server = start_server(env, tmp_path / 'server.log', 'use_map_topic:=true')
    publisher = start_scan_publisher(env, tmp_path / 'pub.log', OFFICE_YAML, TRUTH)
    try:
        server.wait_for_output('map not loaded')
        assert 'origin must be finite' in server.output()
        code, result = localize(env, '--timeout', '10')
        assert code == 1 and result['outcome'] == 'no_map' and 'origin must be finite' in result['message'], result
        pub.publish(office_grid_msg())
        server.wait_for_output('map OccupancyGrid on map: 520 x 360 cells')
        code, result = localize(env, '--timeout', '10')
        assert code == 0, (result, server.output())
        assert_pose_near(pose_of(result), TRUTH)
    finally:
        publisher.stop()
        assert server.stop() == 0
        node.destroy_node()
        context.try_shutdown()


def test_ambiguous_place_publishes_nothing_unless_asked(tmp_path):
    """A four-fold symmetric room: the result says ambiguous, lists the hypotheses, and
    /initialpose stays silent unless the goal asks to publish the best anyway."""
    from global_loc.core.map_io import save_map_yaml
    save_map_yaml(symmetric_room(), tmp_path / 'square.yaml')
    env = isolated_env()
    listener = initialpose_listener(env)
    server = start_server(env, tmp_path / 'server.log', f'map_yaml:={tmp_path / "square.yaml"}')
    publisher = start_scan_publisher(env, tmp_path / 'pub.log', tmp_path / 'square.yaml', Rigid2D(2.0, 1.4, 0.4))
    assert listener.wait_for_publisher('/initialpose')
    try:
        code, result = localize(env, '--timeout', '10')
        assert code == 1 and result['outcome'] == 'ambiguous' and len(result['hypotheses']) >= 4, result
        time.sleep(1.0)
        assert listener.messages['/initialpose'] == []
        code, result = localize(env, '--timeout', '10', '--publish-if-ambiguous')
        assert code == 1 and result['outcome'] == 'ambiguous'
        assert len(listener.wait_for('/initialpose', 1)) == 1
    finally:
        publisher.stop()
        listener.close()
        assert server.stop() == 0


def test_search_limit_and_missing_surf_end_goals_with_their_reason(tmp_path):
    """max_search_s ends a goal that would search for minutes ("search incomplete");
    features_surf without SURF is a bad goal with the reason, not an internal error."""
    from global_loc.core.matchers.features import surf_available
    env = isolated_env()
    server = start_server(env, tmp_path / 'server.log', 'max_search_s:=1.0')
    publisher = start_scan_publisher(env, tmp_path / 'pub.log', OFFICE_YAML, TRUTH)
    try:
        t0 = time.monotonic()
        code, result = localize(env, '--method', 'template_ccoeff', '--angle-step', '0.1', '--timeout', '10')
        assert code == 1 and result['outcome'] == 'search_incomplete', result
        assert '1 s search limit' in result['message'] and time.monotonic() - t0 < 30
        code, result = localize(env, '--method', 'features_sift')     # not in `methods`: never built in a goal
        assert code == 1 and result['outcome'] == 'bad_goal' and 'features_sift is not prepared on this server' in \
            result['message'], result
        if not surf_available():
            code, result = localize(env, '--method', 'features_surf')
            assert code == 1 and result['outcome'] == 'bad_goal' and 'SURF is not in this OpenCV build' in \
                result['message'], result
        assert 'internal error' not in server.output() and 'Traceback' not in server.output()
        assert localize(env, '--timeout', '10')[0] == 0
    finally:
        publisher.stop()
        assert server.stop() == 0
