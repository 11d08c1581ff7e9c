"""Starting and stopping the package's ROS 2 processes (server, sim, client) and
recording topics, for the demo and the tests, in the place of `ros2 launch` (not on
PyPI). A private DDS domain (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, a random
ROS_DOMAIN_ID) keeps runs apart."""
import os
import random
import shutil
import signal
import subprocess
import sys
import threading
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

# DDS ports (RTPS): domain d uses UDP ports PORT_BASE + DOMAIN_GAIN * d onwards, DOMAIN_GAIN of them
PORT_BASE, DOMAIN_GAIN, DOMAINS = 7400, 250, range(1, 102)    # above 101 they reach the ephemeral ports


def domains_in_use(udp_tables=('/proc/net/udp', '/proc/net/udp6')) -> set[int]:
    """The DDS domains some process on this machine has a participant in (a UDP port bound
    in the domain's range)."""
    used = set()
    for table in udp_tables:
        try:
            with open(table) as f:
                lines = f.readlines()[1:]
        except OSError:
            continue
        for line in lines:
            port = int(line.split()[1].rsplit(':', 1)[1], 16)
            if port >= PORT_BASE:
                used.add((port - PORT_BASE) // DOMAIN_GAIN)
    return used


def isolated_env() -> dict:
    """os.environ on a DDS domain of its own: a random one that no process here uses now
    (several test runs at once on one machine: a shared domain mixes their servers)."""
    env = dict(os.environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    free = [d for d in DOMAINS if d not in domains_in_use()]
    env['ROS_DOMAIN_ID'] = str(random.SystemRandom().choice(free or DOMAINS))
    env['PYTHONUNBUFFERED'] = '1'
    return env


def ros2() -> str:
    exe = shutil.which('ros2')
    if not exe:
        raise RuntimeError('no ros2 command on PATH: source env.sh (or use make test / make demo)')
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
                raise RuntimeError(f'process exited ({self.proc.returncode}) before printing {text!r}:\n'
                                   f'{self.output()}')
            time.sleep(0.1)
        raise RuntimeError(f'no {text!r} within {timeout} s:\n{self.output()}')

    def stop(self, timeout: float = 10.0) -> int:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                # Ask for every thread's stack (run_node registers SIGUSR1 with faulthandler)
                # so a hang at exit leaves a trace in the log, then kill.
                os.killpg(self.proc.pid, signal.SIGUSR1)
                time.sleep(1.0)
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
                print(f'{self.log_path}: no exit within {timeout} s of SIGTERM; killed. Its log ends:\n'
                      f'{self.output()[-6000:]}', file=sys.stderr)
        self.log.close()
        return self.proc.returncode


def start_node(env, log_path, executable: str, ready_line: str, *params, params_file=None) -> Process:
    """`ros2 run global_loc EXECUTABLE --ros-args [--params-file F] -p NAME:=VALUE ...`, once it
    logged `ready_line`."""
    args = [ros2(), 'run', 'global_loc', executable, '--ros-args']
    if params_file:
        args += ['--params-file', str(params_file)]
    for p in params:
        args += ['-p', p]
    node = Process(args, env, log_path)
    node.wait_for_output(ready_line)
    return node


def start_server(env, log_path, *params, params_file=None, ready_line='ready: action') -> Process:
    return start_node(env, log_path, 'server', ready_line, *params, params_file=params_file)


def start_sim(env, log_path, *params) -> Process:
    return start_node(env, log_path, 'sim', 'sim ready', *params)


def start_client(env, *args, **popen_kwargs) -> subprocess.Popen:
    """`ros2 run global_loc test_global_loc ARGS` in the background."""
    return subprocess.Popen([ros2(), 'run', 'global_loc', 'test_global_loc', *args], env=env, **popen_kwargs)


def run_client(env, *args, timeout=120.0) -> subprocess.CompletedProcess:
    """The client run to its end, its output captured."""
    client = start_client(env, *args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        stdout, stderr = client.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        client.kill()
        raise
    return subprocess.CompletedProcess(client.args, client.returncode, stdout, stderr)


class TopicRecorder:
    """Records messages of a few topics in this process (its own rclpy context on the
    env's domain), spun in a background thread. `topics`: {name: (msg type, qos)}."""

    def __init__(self, env: dict, topics: dict, node_name: str = 'global_loc_recorder'):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=int(env['ROS_DOMAIN_ID']))
        self.node = rclpy.create_node(node_name, context=self.context)
        self.messages = {name: [] for name in topics}
        self._clients = {}
        for name, (msg_type, qos) in topics.items():
            self.node.create_subscription(msg_type, name, self.messages[name].append, qos)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while not self.stopping.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def wait_for(self, topic: str, count: int, timeout: float = 10.0) -> list:
        deadline = time.monotonic() + timeout
        while len(self.messages[topic]) < count and time.monotonic() < deadline:
            time.sleep(0.05)
        return self.messages[topic]

    def wait_for_publisher(self, topic: str, timeout: float = 10.0) -> bool:
        """Until some node publishes `topic` as seen by discovery (a volatile topic such as
        /initialpose delivers nothing to a subscriber that has not matched yet)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.node.count_publishers(topic) > 0:
                time.sleep(0.2)   # discovery seen; give the reader/writer match a moment
                return True
            time.sleep(0.05)
        return False

    def call(self, srv_type, name: str, request, timeout: float = 30.0):
        """A service call from this node (its executor spins in the background thread);
        AssertionError when the service is absent or does not answer in time."""
        if name not in self._clients:
            self._clients[name] = self.node.create_client(srv_type, name)
        client = self._clients[name]
        assert client.wait_for_service(timeout_sec=10.0), f'no service {name}'
        future = client.call_async(request)
        deadline = time.monotonic() + timeout
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.02)
        assert future.done(), f'{name} did not answer within {timeout} s'
        return future.result()

    def close(self) -> None:
        # Stop and join the spinning thread before tearing the executor down: shutting an
        # executor down while another thread spins it races on its guard condition (seen:
        # the spin thread looping forever, holding the GIL, after close()).
        self.stopping.set()
        self.thread.join(timeout=5.0)
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


def reliable(depth: int = 10, latched: bool = False) -> QoSProfile:
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)
