"""The one way the package's nodes run: init, build, spin until SIGINT/SIGTERM, clean up."""
from __future__ import annotations

import faulthandler
import os
import signal
import sys
import threading
import time
from typing import Callable, Optional

import rclpy
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from .memory import limit_arenas
from .param_types import ParameterError


def run_node(make_node: Callable, make_executor: Optional[Callable[[], Executor]] = None,
             startup_errors: tuple = (), args=None) -> int:
    """Spin the node `make_node()` builds; return the exit code. An exception listed in
    `startup_errors` (e.g. a map that cannot be loaded) is printed as one line and exits 1;
    a parameter it cannot run with (param_types.ParameterError), 2 - a usage error."""
    # `kill -USR1` prints every thread's stack: how a node that does not stop is diagnosed.
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    limit_arenas()       # before any thread starts (memory.py says why)
    # SIGINT and SIGTERM are handled here, not by rclpy: rclpy's handler shuts the context
    # down at once, so a running goal could no longer publish its feedback nor send its
    # result. Here a signal while spinning only asks the loop to stop; the node then winds
    # down (ends its goals, their results are sent) while the executor still spins, and
    # only then is the context shut down. A signal while the node is being built (a long
    # map precomputation) interrupts it.
    stop = _StopRequest()
    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node = executor = None
    code = 0
    try:
        node = make_node()
        executor = make_executor() if make_executor else SingleThreadedExecutor()
        executor.add_node(node)
        stop.spinning = True
        while rclpy.ok() and not stop.requested.is_set():
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except startup_errors as e:
        print(f'{getattr(node, "get_name", lambda: "global_loc")()}: {e}', file=sys.stderr)
        code = 2 if isinstance(e, ParameterError) else 1
    except Exception:
        if rclpy.ok():
            raise
    finally:
        stop.spinning = True      # from here on a further signal is ignored: the stop is under way
        wind_down = getattr(node, 'wind_down', None)
        if wind_down is not None and executor is not None and rclpy.ok():
            _spin_while_winding_down(executor, wind_down())
        if executor is not None:
            # the callbacks handed to threads end first: shutdown destroys the guard
            # condition they signal when they end
            _wait_for_running_callbacks(executor, 1.0)
            executor.shutdown(timeout_sec=1.0)
        if node is not None:
            close = getattr(node, 'close', None)
            if close:
                close()
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code


def exit_process(code: int) -> None:
    """End the process once run_node has shut ROS down: flush and _exit. The interpreter's
    own teardown (numba, OpenCV, numpy, thread pools) takes ~0.5 s after a clean ROS
    shutdown and nothing in it is needed; a node must be gone within a second of SIGTERM
    (measured: 0.77 s -> 0.2 s). An abandoned matchTemplate thread ends with the process."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


class _StopRequest:
    """The SIGINT/SIGTERM handler: sets `requested`; raises KeyboardInterrupt only while
    the node is being built (nothing spins yet to notice the flag)."""

    def __init__(self):
        self.requested = threading.Event()
        self.spinning = False

    def __call__(self, signum, frame):
        first = not self.requested.is_set()
        self.requested.set()
        if first and not self.spinning:
            raise KeyboardInterrupt(f'signal {signum}')


def _wait_for_running_callbacks(executor: Executor, limit_s: float) -> None:
    """Wait until the callbacks a MultiThreadedExecutor handed to its threads have
    returned, before the node is destroyed under them ("cannot use Destroyable because
    destruction was requested"). rclpy Jazzy's Executor.shutdown does not wait for them
    (it skips its wait when it is the call that marked the executor shut down); the
    executor's own list of handed-out callbacks is the only record of them."""
    deadline = time.monotonic() + limit_s
    for future in list(getattr(executor, '_futures', [])):
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.005)


def _spin_while_winding_down(executor: Executor, idle: Callable[[], bool], limit_s: float = 0.8,
                             flush_s: float = 0.1) -> None:
    """Spin until `idle()` (the node's running work has ended) or `limit_s`, then `flush_s`
    more: an action's result is sent by a task the executor runs after the goal's callback
    returned."""
    deadline = time.monotonic() + limit_s
    while not idle() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
    deadline = time.monotonic() + flush_s
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
