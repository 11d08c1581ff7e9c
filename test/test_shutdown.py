"""Stopping in every state, in real processes: a SIGTERM or SIGINT
ends the running goal with a result the client receives ("the server is stopping"),
the server exits promptly and cleanly, and a client whose server disappears gives up
with exit code 3."""
import json
import os
import signal
import subprocess
import time

import pytest
from ros_helpers import TRUTH, start_scan_publisher

from conftest import OFFICE_YAML
from global_loc.testing.processes import isolated_env, start_client, start_server, start_sim

pytestmark = pytest.mark.ros   # real ROS processes (the compat run has no ROS: -m 'not ros')

# Generous against a loaded CI machine; the soak benchmark measures the real figure.
EXIT_WITHIN_S = 5.0


def signal_and_time(process, signum) -> float:
    """Send `signum` to the process group; seconds until it exited (inf if it did not)."""
    t0 = time.monotonic()
    os.killpg(process.proc.pid, signum)
    try:
        process.proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        process.stop(1.0)
        return float('inf')
    return time.monotonic() - t0


def start_goal(env, *args):
    return start_client(env, '--json', *args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def client_result(client, timeout=30):
    out, err = client.communicate(timeout=timeout)
    return client.returncode, (json.loads(out) if out.strip() else None), err


@pytest.mark.parametrize('signum', [signal.SIGTERM, signal.SIGINT])
def test_signal_while_a_goal_waits_for_a_scan_ends_the_goal_and_the_server(tmp_path, signum):
    env = isolated_env()
    server = start_server(env, tmp_path / 'server.log')
    client = start_goal(env, '--timeout', '600')
    try:
        server.wait_for_output('waiting up to')
        seconds = signal_and_time(server, signum)
        code, result, err = client_result(client)
    finally:
        client.kill()
        server.stop()
    log = server.output()
    assert seconds < EXIT_WITHIN_S, f'server took {seconds:.1f} s to exit:\n{log}'
    assert server.proc.returncode == 0 and 'Traceback' not in log, log
    assert result is not None and result['outcome'] == 'canceled' and 'stopping' in result['message'], (result, err)
    assert code == 1


def test_sigterm_while_matching_ends_the_goal_and_the_server(tmp_path):
    env = isolated_env()
    server = start_server(env, tmp_path / 'server.log')
    publisher = start_scan_publisher(env, tmp_path / 'pub.log', OFFICE_YAML, TRUTH)
    client = start_goal(env, '--method', 'template_ccoeff', '--angle-step', '0.2', '--timeout', '10')
    try:
        server.wait_for_output('matching a scan')
        time.sleep(0.5)
        seconds = signal_and_time(server, signal.SIGTERM)
        code, result, err = client_result(client)
    finally:
        client.kill()
        publisher.stop()
        server.stop()
    log = server.output()
    assert seconds < EXIT_WITHIN_S, f'server took {seconds:.1f} s to exit:\n{log}'
    assert server.proc.returncode == 0 and 'Traceback' not in log and 'internal error' not in log, log
    assert result is not None and result['outcome'] == 'canceled' and 'stopping' in result['message'], (result, err)


def test_client_gives_up_with_exit_code_3_when_the_server_dies_mid_goal(tmp_path):
    env = isolated_env()
    server = start_server(env, tmp_path / 'server.log')
    client = start_client(env, '--timeout', '600', stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        server.wait_for_output('waiting up to')
        os.killpg(server.proc.pid, signal.SIGKILL)      # no chance to answer
        server.proc.wait()
        out, err = client.communicate(timeout=30)
    finally:
        client.kill()
        server.stop()
    assert client.returncode == 3, (out, err)
    assert 'server' in err and ('gone' in err or 'disappeared' in err), err


def test_a_timeout_beyond_its_bound_is_a_bad_goal_said_readably(tmp_path):
    """A goal's timeout_s has the bounds of the scan_timeout_s parameter (0.1-600 s); 1e308
    is refused at once, the bound and the value printed short (not 309 digits)."""
    env = isolated_env()
    server = start_server(env, tmp_path / 'server.log')
    try:
        _, result, _ = client_result(start_goal(env, '--timeout', '1e308'))
    finally:
        server.stop()
    assert result['outcome'] == 'bad_goal', result
    assert result['message'] == 'bad request: scan_timeout_s must be in [0.1, 600], got 1e+308', result


@pytest.mark.parametrize('signum', [signal.SIGTERM, signal.SIGINT])
def test_simulator_exits_cleanly_on_a_signal(tmp_path, signum):
    """pybullet's disconnect once raced the step timer (a segfault about 1 in 25)."""
    env = isolated_env()
    for k in range(4):
        sim = start_sim(env, tmp_path / f'sim{k}.log', 'map_yaml:=' + str(OFFICE_YAML))
        time.sleep(0.3 * k)
        seconds = signal_and_time(sim, signum)
        assert sim.proc.returncode == 0 and seconds < EXIT_WITHIN_S, (sim.proc.returncode, sim.output())
