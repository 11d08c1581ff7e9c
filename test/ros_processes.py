"""Helpers for tests that run real ROS 2 processes over real DDS, isolated per test
module by ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a random ROS_DOMAIN_ID."""
import os
import random
import shutil
import signal
import subprocess
import sys
import time

TEST_DIR = os.path.dirname(os.path.abspath(__file__))


def isolated_env() -> dict:
    env = dict(os.environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['ROS_DOMAIN_ID'] = str(random.SystemRandom().randint(1, 101))
    env['PYTHONUNBUFFERED'] = '1'
    return env


def ros2() -> str:
    exe = shutil.which('ros2')
    assert exe, 'no ros2 command on PATH: run the tests through `make test` (or source env.sh)'
    return exe


class Process:
    """A background process with its output in a log file; stopped with SIGTERM."""

    def __init__(self, args, env, log_path):
        self.log_path = log_path
        self.log = open(log_path, 'w')
        self.proc = subprocess.Popen(args, env=env, stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True)

    def output(self) -> str:
        with open(self.log_path) as f:
            return f.read()

    def wait_for_output(self, text: str, timeout: float = 30.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if text in self.output():
                return
            if self.proc.poll() is not None:
                raise AssertionError(f'process exited ({self.proc.returncode}) before printing {text!r}:\n{self.output()}')
            time.sleep(0.1)
        raise AssertionError(f'no {text!r} within {timeout} s:\n{self.output()}')

    def stop(self, timeout: float = 10.0) -> int:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        self.log.close()
        return self.proc.returncode


def start_server(env, log_path, *params) -> Process:
    args = [ros2(), 'run', 'global_loc', 'server', '--ros-args']
    for p in params:
        args += ['-p', p]
    server = Process(args, env, log_path)
    server.wait_for_output('ready: action')
    return server


def start_scan_publisher(env, log_path, map_yaml, pose, rate=5.0) -> Process:
    return Process([sys.executable, os.path.join(TEST_DIR, 'scan_publisher.py'), map_yaml,
                    *map(str, pose), str(rate)], env, log_path)


def run_client(env, *args, timeout=120.0) -> subprocess.CompletedProcess:
    return subprocess.run([ros2(), 'run', 'global_loc', 'test_global_loc', *args], env=env, capture_output=True,
                          text=True, timeout=timeout)
