"""ROS users write `5` for five seconds (launch files, params files, `ros2 param set`): every
double parameter of the server and the simulator takes an integer as the same double; a
value of another kind, or out of its range, is one line naming the parameter - the server
stays unconfigured, the simulator exits with code 2 - never a traceback. Real processes."""
import subprocess

import pytest
from ros_helpers import TRUTH, localize, pose_of, start_scan_publisher
from sensor_msgs.msg import LaserScan
from test_runtime_changes import Operator

from conftest import OFFICE_YAML, assert_pose_near
from global_loc.ros.parameters import SPECS
from global_loc.testing.processes import TopicRecorder, isolated_env, reliable, ros2, start_server, start_sim

pytestmark = pytest.mark.ros

# every double parameter of the server whose default is a whole number, written as an integer
WHOLE_DOUBLES = [f'{s.name}:={int(s.default)}' for s in SPECS
                 if isinstance(s.default, float) and s.default == int(s.default) and s.name != 'scan_timeout_s']


def test_the_server_takes_integers_for_its_doubles_at_start_and_when_set(tmp_path):
    assert len(WHOLE_DOUBLES) >= 10, WHOLE_DOUBLES
    env = isolated_env()
    op = Operator(env)
    server = start_server(env, tmp_path / 'server.log', *WHOLE_DOUBLES, 'scan_timeout_s:=1')
    try:
        code, result = localize(env)                # no scans yet: the timeout read as 1.0 s
        assert result['outcome'] == 'no_scan' and 'within 1.0 s' in result['message'], result
        assert op.set(scan_timeout_s=2)[0].successful           # an integer, live
        code, result = localize(env)
        assert result['outcome'] == 'no_scan' and 'within 2.0 s' in result['message'], result
        assert op.set(health__degraded_fit=1)[0].successful     # a non-whole default, set to an integer
        refused = op.set(max_search_s='five')[0]
        assert not refused.successful and 'max_search_s' in refused.reason and 'a number in' in refused.reason
        publisher = start_scan_publisher(env, tmp_path / 'pub.log', OFFICE_YAML, TRUTH)
        try:
            code, result = localize(env, '--timeout', '10')
            assert code == 0, result
            assert_pose_near(pose_of(result), TRUTH)
        finally:
            publisher.stop()
        assert 'Traceback' not in server.output()
    finally:
        op.close()
        assert server.stop() == 0


@pytest.mark.parametrize('bad, says', [('max_search_s:=five', "'five' is not a number (a number in"),
                                       ('relocalize.max_attempts:=many', 'relocalize.max_attempts')])
def test_a_server_parameter_of_the_wrong_kind_is_one_line_and_no_configured_node(tmp_path, bad, says):
    env = isolated_env()
    server = start_server(env, tmp_path / 'server.log', bad, ready_line='configure failed')
    try:
        failed = [line for line in server.output().splitlines() if 'configure failed' in line]
        assert len(failed) == 1 and says in failed[0], server.output()
        assert 'Traceback' not in server.output()
        code, result = localize(env, '--timeout', '2')
        assert result['outcome'] == 'not_active' and bad.split(':=')[0] in result['message'], result
    finally:
        assert server.stop() == 0


def test_the_simulator_takes_integers_for_its_doubles(tmp_path):
    env = isolated_env()
    recorder = TopicRecorder(env, {'/scan': (LaserScan, reliable())})
    sim = start_sim(env, tmp_path / 'sim.log', 'x:=3', 'y:=4', 'yaw:=1', 'fov_deg:=180', 'range_max:=10',
                    'rate_hz:=5', 'noise_std:=0', 'dropout:=0', 'odom_noise:=0', 'odom_drift:=0')
    try:
        scans = recorder.wait_for('/scan', 3)
        assert len(scans) >= 3
        scan = scans[-1]
        assert scan.range_max == pytest.approx(10.0) and scan.scan_time == pytest.approx(0.2)
        assert scan.angle_max - scan.angle_min == pytest.approx(3.14159, abs=0.01)
        assert 'Traceback' not in sim.output()
    finally:
        recorder.close()
        assert sim.stop() == 0


@pytest.mark.parametrize('bad, says', [('rate_hz:=-5.0', 'parameter rate_hz: '),
                                       ('rate_hz:=fast', "rate_hz: 'fast' is not a number"),
                                       ('num_beams:=0', 'parameter num_beams: '),
                                       ('range_max:=-1', 'range_max: -1.0 is outside [0.01, 1000.0]'),
                                       ('range_min:=30', 'range_max: 20.0 must exceed range_min')])
def test_a_simulator_parameter_out_of_range_exits_2_with_one_line(tmp_path, bad, says):
    run = subprocess.run([ros2(), 'run', 'global_loc', 'sim', '--ros-args', '-p', bad], env=isolated_env(),
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2, run.stdout + run.stderr
    lines = [line for line in run.stderr.splitlines() if 'parameter' in line]
    assert len(lines) == 1 and says in lines[0] and 'Traceback' not in run.stdout + run.stderr, run.stderr
