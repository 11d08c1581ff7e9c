"""The server with a map set, in real processes (simulator node + server + client): it
localizes the simulated robot on the map it is on and says which, publishes /initialpose
only for an answer on the map /map serves (served_map), says the robot's map on the
latched ~/current_map, and answers two identical floors `ambiguous` until the goal names one."""
import json

import numpy as np
import pytest
from geometry_msgs.msg import PoseWithCovarianceStamped
from std_msgs.msg import String

from conftest import OFFICE_YAML, assert_pose_near
from global_loc.core.map_io import load_map_yaml, make_map, save_map_yaml
from global_loc.core.transform import Rigid2D
from global_loc.ros.convert import pose_from_msg
from global_loc.sim.simulator import BASE_T_LASER
from global_loc.testing.processes import TopicRecorder, isolated_env, reliable, run_client, start_server, start_sim

pytestmark = pytest.mark.ros

START = Rigid2D(3.0, 4.0, 0.7)       # an office pose the sim suite localizes confidently


def client(env, *args) -> dict:
    return json.loads(run_client(env, '--json', '--timeout', '10', *args).stdout)


def topics() -> dict:
    return {'/initialpose': (PoseWithCovarianceStamped, reliable()),
            '/global_loc_server/current_map': (String, reliable(latched=True))}


def test_a_map_set_answers_on_the_robots_map_and_publishes_only_on_the_served_one(tmp_path):
    office = load_map_yaml(OFFICE_YAML)
    mirror = tmp_path / 'mirror.yaml'            # another building: the office's mirror image
    save_map_yaml(make_map(np.flipud(office.occupancy).copy(), office.resolution, office.origin), mirror)
    env = isolated_env()
    sim = start_sim(env, tmp_path / 'sim.log', f'x:={START.x}', f'y:={START.y}', f'yaw:={START.yaw}')
    server = start_server(env, tmp_path / 'server.log', f'laser_x:={BASE_T_LASER.x}',
                          f'maps:=[mirror={mirror}, office={OFFICE_YAML}]')       # /map serves the first: mirror
    recorder = TopicRecorder(env, topics())
    try:
        assert recorder.wait_for_publisher('/initialpose')
        result = client(env)
        assert result['success'] and result['map'] == 'office', result
        assert_pose_near(Rigid2D(**{k: result['pose'][k] for k in ('x', 'y', 'yaw')}), START, 0.3, 5.0)
        assert 'the answer is on map office, /map serves mirror' in result['message']
        assert recorder.wait_for('/global_loc_server/current_map', 1)[-1].data == 'office'
        assert not recorder.messages['/initialpose']          # the served map is another floor's
        assert 'map office' in server.output() and 'map mirror' in server.output()
    finally:
        recorder.close()
        assert server.stop() == 0, server.output()[-3000:]
        assert sim.stop() == 0


def test_identical_floors_are_ambiguous_until_the_goal_names_one(tmp_path):
    env = isolated_env()
    sim = start_sim(env, tmp_path / 'sim.log', f'x:={START.x}', f'y:={START.y}', f'yaw:={START.yaw}')
    server = start_server(env, tmp_path / 'server.log', f'laser_x:={BASE_T_LASER.x}', 'served_map:=floor_2',
                          f'maps:=[floor_1={OFFICE_YAML}, floor_2={OFFICE_YAML}]')
    recorder = TopicRecorder(env, topics())
    try:
        assert recorder.wait_for_publisher('/initialpose')
        guess = client(env)
        assert guess['outcome'] == 'ambiguous' and not guess['success'], guess
        assert {h['map'] for h in guess['hypotheses'][:2]} == {'floor_1', 'floor_2'}
        assert not recorder.messages['/initialpose']
        named = client(env, '--map', 'floor_2')
        assert named['success'] and named['map'] == 'floor_2', named
        published = recorder.wait_for('/initialpose', 1)
        assert_pose_near(pose_from_msg(published[-1].pose.pose), START, 0.3, 5.0)
        bad = client(env, '--map', 'floor_9')
        assert bad['outcome'] == 'bad_goal' and 'no map named floor_9' in bad['message'], bad
    finally:
        recorder.close()
        assert server.stop() == 0, server.output()[-3000:]
        assert sim.stop() == 0
