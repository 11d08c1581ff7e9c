"""The server as a nav2 robot has it, in real processes over DDS: lifecycle transitions
(lifecycle_msgs services, as nav2's lifecycle_manager calls them), the std_srvs triggers,
the RViz topics, the parameters file and search priors through the action."""
import json
import os
import subprocess
import time

import pytest
import yaml
from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from nav_msgs.msg import OccupancyGrid
from ros_helpers import TRUTH, ApiLocalizer, start_scan_publisher
from std_srvs.srv import Empty, Trigger
from visualization_msgs.msg import Marker, MarkerArray

from conftest import OFFICE_YAML, REPO_ROOT, assert_pose_near, symmetric_room
from global_loc.core.map_io import save_map_yaml
from global_loc.core.outcome import Outcome
from global_loc.core.transform import Rigid2D
from global_loc.ros.api import LocalizeGoal
from global_loc.ros.convert import pose_from_msg
from global_loc.testing.processes import TopicRecorder, isolated_env, reliable, start_client, start_server

pytestmark = pytest.mark.ros   # real ROS processes (the compat run has no ROS: -m 'not ros')

PARAMS_FILE = os.path.join(REPO_ROOT, 'config', 'global_loc.yaml')


def call(recorder: TopicRecorder, srv_type, name: str, request, timeout: float = 30.0):
    return recorder.call(srv_type, name, request, timeout)


def transition(recorder, transition_id: int) -> bool:
    return call(recorder, ChangeState, '/global_loc_server/change_state',
                ChangeState.Request(transition=Transition(id=transition_id))).success


def state(recorder) -> str:
    return call(recorder, GetState, '/global_loc_server/get_state', GetState.Request()).current_state.label


@pytest.fixture
def ros(tmp_path):
    """A private domain with a scan publisher at TRUTH, a recorder node and the Python
    API's localizer (the client: these tests are of the server); stops what it started."""
    env = isolated_env()
    recorder = TopicRecorder(env, {'/initialpose': (PoseWithCovarianceStamped, reliable())}, 'test_nav2')
    publisher = start_scan_publisher(env, tmp_path / 'pub.log', OFFICE_YAML, TRUTH)
    localizer = ApiLocalizer(env)
    servers = []
    yield env, recorder, servers, localizer.api
    localizer.close()
    for server in servers:
        assert server.stop() == 0, server.output()
    publisher.stop()
    recorder.close()


def test_lifecycle_manager_drives_a_server_started_without_autostart(ros, tmp_path):
    env, recorder, servers, api = ros
    servers.append(start_server(env, tmp_path / 'server.log', 'autostart:=false', ready_line='unconfigured'))
    assert state(recorder) == 'unconfigured'
    result = api.localize(LocalizeGoal(timeout_s=10))
    assert result.outcome == Outcome.NOT_ACTIVE and result.status == 'aborted', result
    assert transition(recorder, Transition.TRANSITION_CONFIGURE) and state(recorder) == 'inactive'
    assert api.localize(LocalizeGoal(timeout_s=10)).outcome == Outcome.NOT_ACTIVE
    assert transition(recorder, Transition.TRANSITION_ACTIVATE) and state(recorder) == 'active'
    result = api.localize(LocalizeGoal(timeout_s=10))
    assert result.success and result.outcome == Outcome.LOCALIZED, result
    assert transition(recorder, Transition.TRANSITION_DEACTIVATE) and state(recorder) == 'inactive'
    assert api.localize(LocalizeGoal(timeout_s=10)).outcome == Outcome.NOT_ACTIVE
    assert transition(recorder, Transition.TRANSITION_CLEANUP) and state(recorder) == 'unconfigured'
    assert 'cleaned up: map dropped' in servers[0].output()


def bring_up_as_nav2_does(recorder) -> list[bool]:
    """nav2's lifecycle_manager at start-up, for one node: configure then activate, each
    by transition *id* (ChangeState with an empty label), then get_state; the answers."""
    answers = []
    for transition_id in (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
        answers.append(transition(recorder, transition_id))
        state(recorder)
    return answers


@pytest.mark.parametrize('autostart', [True, False])
def test_a_lifecycle_manager_asking_by_id_is_answered_and_the_server_keeps_serving(ros, tmp_path, autostart):
    """By id, a transition the state does not have (configure while active: a server up
    with autostart under nav2's lifecycle_manager) is answered success=false, as rclcpp
    nodes answer; rclpy alone raised into the executor and the process died."""
    env, recorder, servers, api = ros
    server = start_server(env, tmp_path / 'server.log', f'autostart:={str(autostart).lower()}',
                          ready_line='ready: action' if autostart else 'unconfigured')
    servers.append(server)
    assert bring_up_as_nav2_does(recorder) == ([False, False] if autostart else [True, True]), server.output()
    assert state(recorder) == 'active'
    bogus = [ChangeState.Request(transition=Transition(id=99)),
             ChangeState.Request(transition=Transition(id=Transition.TRANSITION_CLEANUP)),   # not from active
             ChangeState.Request(transition=Transition(label='no_such_transition'))]
    for request in bogus:
        assert not call(recorder, ChangeState, '/global_loc_server/change_state', request).success
    assert server.proc.poll() is None, server.output()
    assert state(recorder) == 'active'
    assert 'change_state refused: transition id 99 is not available in state active' in server.output()
    assert api.localize(LocalizeGoal(timeout_s=10)).success, server.output()
    assert transition(recorder, Transition.TRANSITION_DEACTIVATE) and state(recorder) == 'inactive'
    assert not transition(recorder, Transition.TRANSITION_DEACTIVATE)     # again: not from inactive
    assert transition(recorder, Transition.TRANSITION_ACTIVATE) and api.localize(LocalizeGoal(timeout_s=10)).success


def test_deactivate_during_a_goal_ends_it_and_refuses_the_next(ros, tmp_path):
    env, recorder, servers, api = ros
    server = start_server(env, tmp_path / 'server.log')
    servers.append(server)
    slow = start_client(env, '--json', '--method', 'template_ccoeff', '--angle-step', '0.5', '--timeout', '10',
                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 30
    while 'matching a scan' not in server.output() and time.monotonic() < deadline:
        time.sleep(0.1)
    t0 = time.monotonic()
    assert transition(recorder, Transition.TRANSITION_DEACTIVATE)
    assert time.monotonic() - t0 < 5.0
    out, err = slow.communicate(timeout=30)
    result = json.loads(out)
    assert result['outcome'] == 'canceled' and 'stopping' in result['message'], (result, err)
    assert api.localize().outcome == Outcome.NOT_ACTIVE
    assert transition(recorder, Transition.TRANSITION_ACTIVATE)
    assert api.localize(LocalizeGoal(timeout_s=10)).success


def test_trigger_services_localize_and_publish_and_rviz_topics_reach_a_late_subscriber(ros, tmp_path):
    env, recorder, servers, _ = ros
    servers.append(start_server(env, tmp_path / 'server.log'))
    assert recorder.wait_for_publisher('/initialpose')
    reply = call(recorder, Trigger, '/global_loc_server/trigger', Trigger.Request())
    assert reply.success and reply.message.startswith('localized') and '; x=' in reply.message, reply.message
    published = recorder.wait_for('/initialpose', 1)
    assert len(published) == 1
    assert_pose_near(pose_from_msg(published[0].pose.pose), TRUTH)
    call(recorder, Empty, '/global_loc_server/reinitialize_global_localization', Empty.Request())
    assert len(recorder.wait_for('/initialpose', 2)) == 2
    # RViz joining now still gets the last localization (transient local, depth 1)
    latched = reliable(depth=1, latched=True)
    late = TopicRecorder(env, {'/global_loc_server/hypotheses': (PoseArray, latched),
                               '/global_loc_server/hypothesis_markers': (MarkerArray, latched),
                               '/global_loc_server/local_map': (OccupancyGrid, latched)}, 'late_rviz')
    try:
        hypotheses = late.wait_for('/global_loc_server/hypotheses', 1)
        markers = late.wait_for('/global_loc_server/hypothesis_markers', 1)
        local_map = late.wait_for('/global_loc_server/local_map', 1)
        assert len(hypotheses) == len(markers) == len(local_map) == 1
        assert hypotheses[0].header.frame_id == 'map'
        assert_pose_near(pose_from_msg(hypotheses[0].poses[0]), TRUTH)
        arrows = [m for m in markers[0].markers if m.action == Marker.ADD and m.type == Marker.ARROW]
        assert len(arrows) == len(hypotheses[0].poses) and arrows[0].color.g > arrows[0].color.r   # chosen: green
        labels = [m.text for m in markers[0].markers if m.type == Marker.TEXT_VIEW_FACING]
        assert labels[0].startswith('1: ') and ' on ' in labels[0], labels      # each names its map
        grid = local_map[0]
        assert grid.header.frame_id == 'map' and grid.info.resolution == pytest.approx(0.05)
        assert sum(v == 100 for v in grid.data) > 100 and set(grid.data) <= {100, -1}
    finally:
        late.close()


def test_parameters_file_is_read_and_lists_every_parameter(ros, tmp_path):
    """The shipped file starts a working server; a copy with one value changed changes it."""
    env, recorder, servers, api = ros
    servers.append(start_server(env, tmp_path / 'server.log', params_file=PARAMS_FILE))
    assert api.localize(LocalizeGoal(timeout_s=10)).success
    assert servers.pop().stop() == 0
    doc = yaml.safe_load(open(PARAMS_FILE))
    doc['global_loc_server']['ros__parameters']['bnb']['max_nodes'] = 50
    changed = tmp_path / 'changed.yaml'
    changed.write_text(yaml.safe_dump(doc))
    servers.append(start_server(env, tmp_path / 'server2.log', params_file=changed))
    assert api.wait_until_active(30.0)      # a goal sent right after a restart can be lost in discovery
    result = api.localize(LocalizeGoal(timeout_s=10))
    assert not result.success and result.outcome == Outcome.SEARCH_INCOMPLETE, result


def test_parameters_file_has_every_declared_parameter_with_its_default():
    """Against the declarations themselves (parameters.SPECS: what the server declares)."""
    from global_loc.ros.parameters import SPECS

    def flat(d, prefix=''):
        out = {}
        for k, v in d.items():
            out.update(flat(v, f'{prefix}{k}.') if isinstance(v, dict) else {f'{prefix}{k}': v})
        return out

    params = flat(yaml.safe_load(open(PARAMS_FILE))['global_loc_server']['ros__parameters'])
    declared = {spec.name: spec.default for spec in SPECS}
    lists = {name for name, default in declared.items() if isinstance(default, list)}    # approx takes no lists
    assert {name: params.get(name) for name in lists} == {name: declared[name] for name in lists}
    assert {k: v for k, v in params.items() if k not in lists} == \
        pytest.approx({k: v for k, v in declared.items() if k not in lists})


def test_search_prior_settles_a_symmetric_room(tmp_path):
    """Four-fold symmetric: ambiguous alone, localized with a prior of the right quarter."""
    save_map_yaml(symmetric_room(), tmp_path / 'square.yaml')
    env = isolated_env()
    truth = Rigid2D(2.0, 1.4, 0.4)
    server = start_server(env, tmp_path / 'server.log', f'map_yaml:={tmp_path / "square.yaml"}')
    publisher = start_scan_publisher(env, tmp_path / 'pub.log', tmp_path / 'square.yaml', truth)
    localizer = ApiLocalizer(env)
    try:
        assert localizer.api.localize(LocalizeGoal(timeout_s=10)).outcome == Outcome.AMBIGUOUS
        result = localizer.api.localize(LocalizeGoal(timeout_s=10, near=(1.5, 1.5, 0.0), radius_m=1.5))
        assert result.success and result.outcome == Outcome.LOCALIZED, result
        assert_pose_near(result.pose, truth)
        assert 0 <= result.scan_age_s < 5 and result.scan_stamp > 0
    finally:
        localizer.close()
        publisher.stop()
        assert server.stop() == 0
