"""What keeps the server's executor spinning whatever a callback meets: guarded callbacks
(an exception logged, throttled, and counted on /diagnostics), the count of requests in
flight (the shutdown waits for them), and the one-off warning about a peer server."""
from __future__ import annotations

import contextlib
import functools
import threading
import traceback


def guard(callback, errors: dict, logger):
    """`callback` for a timer, subscription or service: an exception is logged (throttled),
    counted in `errors` by the callback's name (/diagnostics shows them), and the node
    keeps spinning."""
    name = getattr(callback, '__name__', 'callback')

    @functools.wraps(callback)
    def run(*args):
        try:
            return callback(*args)
        except Exception as e:
            errors[name] = errors.get(name, 0) + 1
            logger.error(f'{name} failed ({errors[name]} so far): {type(e).__name__}: {e}\n'
                         f'{traceback.format_exc()}', throttle_duration_sec=10.0)
            return args[1] if len(args) == 2 else None     # a service still answers (its response)
    return run


class InFlight:
    """Counts requests (goal, service call, relocalization) until their handlers return."""

    def __init__(self):
        self.count, self._lock = 0, threading.Lock()

    @contextlib.contextmanager
    def __call__(self):
        with self._lock:
            self.count += 1
        try:
            yield
        finally:
            with self._lock:
                self.count -= 1


def warn_about_peers(node) -> None:
    """Another global_loc server on this domain would execute every goal too (both publish
    poses): said once, as an error."""
    peers = [ns for name, ns in node.get_node_names_and_namespaces() if name == node.get_name()]
    if len(peers) > 1:
        node.get_logger().error(f'{len(peers)} nodes named {node.get_name()} on this ROS domain: each executes '
                                f'every goal and publishes its poses; run one per domain or rename one')
