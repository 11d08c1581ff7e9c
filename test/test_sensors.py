"""Several sensors in the server, in real processes: two narrow lasers that
together localize where one alone cannot, the simulator's 3D lidar alone, and every bad
input - a sensor going silent, one with no mounting, clocks far apart, clouds whose
layout does not fit their data - said in the result and on /diagnostics, the view going
on with the sensors that work."""
import json
import math
import os
import sys
import threading
import time

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from ros_helpers import TRUTH, localize, pose_of

from conftest import OFFICE_YAML, TEST_DIR, assert_pose_near
from global_loc.core.paths import sim_params_file
from global_loc.core.transform import Rigid2D
from global_loc.sim.robot import LIDAR_MOUNT
from global_loc.testing.processes import Process, TopicRecorder, isolated_env, start_server, start_sim

pytestmark = pytest.mark.ros   # real ROS processes

FRONT = [0.16, 0.0, 0.3, 0.0, 0.0, 0.0]
REAR = [-0.22, 0.0, 0.3, 0.0, 0.0, math.pi]
# An office pose where a 100-degree laser at the front alone and one at the back alone are
# each ambiguous, both together confident (test_view found it by a sweep).
TWO_LASER_POSE = Rigid2D(6.975, 14.825, 2.4987)


def narrow(topic, mount, frame):
    return {'topic': topic, 'kind': 'scan', 'mount': mount, 'fov': 100.0, 'beams': 201, 'frame': frame,
            'range_max': 8.0}


def start_sensors(env, log_path, pose: Rigid2D, sensors: list) -> Process:
    return Process([sys.executable, os.path.join(TEST_DIR, 'sensor_publisher.py'), str(OFFICE_YAML),
                    *map(str, pose.as_tuple()), json.dumps(sensors)], env, log_path)


def values_of(recorder: TopicRecorder) -> dict:
    """The newest /diagnostics status's key/values."""
    msgs = recorder.wait_for('/diagnostics', 1)
    assert msgs, 'nothing on /diagnostics'
    return {kv.key: kv.value for kv in msgs[-1].status[0].values}


def mount_param(name, mount):
    return f'sensors.{name}.mount:=[{", ".join(repr(float(v)) for v in mount)}]'


def test_two_narrow_lasers_localize_together_and_a_silent_one_is_said(tmp_path):
    env = isolated_env()
    rear_silent = tmp_path / 'rear_silent'
    both = start_sensors(env, tmp_path / 'both.log', TWO_LASER_POSE,
                         [narrow('/scan', FRONT, 'laser'),
                          {**narrow('/scan_rear', REAR, 'laser_rear'), 'silent_if': str(rear_silent)}])
    server = start_server(env, tmp_path / 'server.log', f'map_yaml:={OFFICE_YAML}', 'scan_topics:=[/scan, /scan_rear]',
                          mount_param('scan', FRONT), mount_param('scan_rear', REAR), 'health.period_s:=0.2')
    recorder = TopicRecorder(env, {'/diagnostics': (DiagnosticArray, 10)})
    try:
        code, result = localize(env, '--timeout', '20', '--no-publish')
        assert code == 0 and result['outcome'] == 'localized', result
        assert_pose_near(pose_of(result), TWO_LASER_POSE)
        assert '/scan (' in result['message'] and '/scan_rear (' in result['message'], result['message']
        rear_silent.touch()
        time.sleep(0.5)
        code, result = localize(env, '--timeout', '20', '--no-publish')
        assert result['outcome'] not in ('localized', 'no_scan', 'unusable_scan'), result   # searched, not sure
        assert '/scan_rear: silent' in result['message'], result['message']
        recorder.messages['/diagnostics'].clear()
        values = values_of(recorder)
        assert 'silent' in values['last view'] and 'sensor /scan_rear' in values, values
    finally:
        recorder.close()
        both.stop()
        assert server.stop() == 0, server.output()


def test_bad_sensors_are_left_out_with_their_reasons(tmp_path):
    side = [0.0, 0.1, 0.3, 0.0, 0.0, 0.0]
    sensors = [{'topic': '/scan', 'kind': 'scan'},
               {'topic': '/scan_side', 'kind': 'scan', 'mount': side, 'frame': 'laser_side'},
               {'topic': '/scan_nomount', 'kind': 'scan', 'frame': 'laser_nomount'},
               {'topic': '/scan_clock', 'kind': 'scan', 'mount': side, 'frame': 'laser_clock', 'stamp_offset_s': -50.0},
               {'topic': '/cloud_no_xyz', 'kind': 'cloud_no_xyz'},
               {'topic': '/cloud_point_step', 'kind': 'cloud_bad_point_step'},
               {'topic': '/cloud_row_step', 'kind': 'cloud_bad_row_step'}]
    env = isolated_env()
    publisher = start_sensors(env, tmp_path / 'sensors.log', TRUTH, sensors)
    server = start_server(env, tmp_path / 'server.log', f'map_yaml:={OFFICE_YAML}',
                          'scan_topics:=[/scan, /scan_side, /scan_nomount, /scan_clock]',
                          'cloud_topics:=[/cloud_no_xyz, /cloud_point_step, /cloud_row_step]',
                          mount_param('scan_side', side), mount_param('scan_clock', side), 'health.period_s:=0.2')
    recorder = TopicRecorder(env, {'/diagnostics': (DiagnosticArray, 10)})
    try:
        code, result = localize(env, '--timeout', '20', '--no-publish')
        message = result['message']
        assert code == 0 and result['outcome'] == 'localized', result
        assert_pose_near(pose_of(result), TRUTH)
        assert '/scan (' in message and '/scan_side (' in message, message
        assert '/scan_nomount: NoMounting: no mounting' in message and 'sensors.scan_nomount.mount' in message
        assert '/scan_clock: clocks far apart' in message, message
        assert '/cloud_no_xyz: ViewError: cloud unusable: point cloud has no x/y/z field' in message, message
        assert '/cloud_point_step: ViewError: cloud unusable' in message and 'point_step' in message, message
        assert '/cloud_row_step: ViewError: cloud unusable' in message and 'row_step' in message, message
        recorder.messages['/diagnostics'].clear()
        values = values_of(recorder)
        assert 'no x/y/z field' in values['sensor /cloud_no_xyz problem'], values
        assert 'no mounting' in values['sensor /scan_nomount problem'], values
        assert 'clocks far apart' in values['last view'], values
        assert server.proc.poll() is None and not any(k.startswith('errors.') for k in values), values
    finally:
        recorder.close()
        publisher.stop()
        assert server.stop() == 0, server.output()


def test_only_broken_sensors_is_an_unusable_scan_saying_each(tmp_path):
    env = isolated_env()
    publisher = start_sensors(env, tmp_path / 'sensors.log', TRUTH, [{'topic': '/points', 'kind': 'cloud_no_xyz'}])
    server = start_server(env, tmp_path / 'server.log', f'map_yaml:={OFFICE_YAML}', 'scan_topics:=[]',
                          'cloud_topics:=[/points]', mount_param('points', LIDAR_MOUNT.as_tuple()))
    try:
        code, result = localize(env, '--timeout', '20', '--no-publish')
        assert result['outcome'] == 'unusable_scan', result
        assert '/points: ViewError: cloud unusable: point cloud has no x/y/z field' in result['message'], result
    finally:
        publisher.stop()
        assert server.stop() == 0, server.output()


def test_a_laser_that_starts_late_beside_a_broken_cloud_is_waited_for(tmp_path):
    """The broken cloud's messages come first; the request waits for the laser that has said
    nothing yet (within its scan timeout) instead of ending on the cloud alone."""
    env = isolated_env()
    laser_off = tmp_path / 'laser_off'
    laser_off.touch()
    publisher = start_sensors(env, tmp_path / 'sensors.log', TRUTH,
                              [{'topic': '/scan', 'kind': 'scan', 'silent_if': str(laser_off)},
                               {'topic': '/points', 'kind': 'cloud_no_xyz'}])
    server = start_server(env, tmp_path / 'server.log', f'map_yaml:={OFFICE_YAML}', 'scan_topics:=[/scan]',
                          'cloud_topics:=[/points]', mount_param('points', LIDAR_MOUNT.as_tuple()))
    waiting = threading.Event()

    def switch_on_once_the_server_waits():       # the laser starts only while the request waits for it
        while not waiting.wait(0.1):
            if 'no usable view yet' in server.output():
                laser_off.unlink()
                return
    switch_on = threading.Thread(target=switch_on_once_the_server_waits, daemon=True)
    try:
        switch_on.start()
        code, result = localize(env, '--timeout', '20', '--no-publish')
        assert code == 0 and result['outcome'] == 'localized', result
        assert_pose_near(pose_of(result), TRUTH)
        assert '/points: ViewError: cloud unusable' in result['message'], result['message']
    finally:
        waiting.set()
        publisher.stop()
        assert server.stop() == 0, server.output()


def test_the_simulated_3d_lidar_alone_localizes(tmp_path):
    env = isolated_env()
    start = TRUTH
    sim = start_sim(env, tmp_path / 'sim.log', f'map_yaml:={OFFICE_YAML}', 'lidar3d:=true', f'x:={start.x}',
                    f'y:={start.y}', f'yaw:={start.yaw}')
    # the simulator's mountings as shipped (config/sim.yaml): no tf2 here, nothing else says where the lidar sits
    server = start_server(env, tmp_path / 'server.log', f'map_yaml:={OFFICE_YAML}', 'scan_topics:=[]',
                          'cloud_topics:=[/points]', params_file=sim_params_file())
    try:
        code, result = localize(env, '--timeout', '30', '--no-publish')
        assert code == 0 and result['outcome'] == 'localized', result
        assert_pose_near(pose_of(result), start)
        assert '/points (' in result['message'] or 'points' in server.output(), result
    finally:
        sim.stop()
        assert server.stop() == 0, server.output()
