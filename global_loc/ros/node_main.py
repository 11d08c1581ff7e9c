"""The one way the package's nodes run: init, build, spin until SIGINT/SIGTERM, clean up."""
from __future__ import annotations

import faulthandler
import signal
import sys
from typing import Callable, Optional

import rclpy
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor


def run_node(make_node: Callable, make_executor: Optional[Callable[[], Executor]] = None,
             startup_errors: tuple = (), args=None) -> int:
    """Spin the node `make_node()` builds; return the exit code. An exception listed in
    `startup_errors` (e.g. a map that cannot be loaded) is printed as one line and exits 1."""
    # `kill -USR1` prints every thread's stack: how a node that does not stop is diagnosed.
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    # rclpy's own SIGTERM handler shuts the context down and wakes the executor, but in
    # fresh-clone CI a server has stayed in its wait 10 s after a SIGTERM (three times so
    # far; the SIGUSR1 trace shows the main thread in wait_set.wait). rclpy chains to
    # the handler installed before init, and the spin below returns to Python twice a
    # second, so this one ends the node either way.
    signal.signal(signal.SIGTERM, _raise_keyboard_interrupt)
    rclpy.init(args=args)
    node = executor = None
    code = 0
    try:
        node = make_node()
        executor = make_executor() if make_executor else SingleThreadedExecutor()
        executor.add_node(node)
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.5)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except startup_errors as e:
        print(f'{getattr(node, "get_name", lambda: "global_loc")()}: {e}', file=sys.stderr)
        code = 1
    except Exception:
        if rclpy.ok():
            raise
        # SIGINT/SIGTERM shut the context down under a running callback or the constructor
        # (its publish then fails): that is the requested stop, not a crash.
    finally:
        stop = getattr(node, 'stop_work', None)
        if stop:
            stop()        # end running work (a goal) first, so the executor's threads can be joined
        if executor is not None:
            executor.shutdown(timeout_sec=5.0)   # join the executor's worker threads
        if node is not None:
            close = getattr(node, 'close', None)
            if close:
                close()
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code


def _raise_keyboard_interrupt(signum, frame):
    raise KeyboardInterrupt(f'signal {signum}')
