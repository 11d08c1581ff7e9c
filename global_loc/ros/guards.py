"""What keeps the server's executor spinning whatever a callback meets: guarded callbacks
(an exception logged, throttled, and counted on /diagnostics), the count of requests in
flight (the shutdown waits for them), a lifecycle `~/change_state` that answers every
request, the one-off warning about a peer server, and the wait for a pose's subscriber."""
from __future__ import annotations

import contextlib
import functools
import threading
import time
import traceback

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy


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


PEER_CHECKS = 5     # discovery can take seconds on a loaded machine: look a few times, warn once


def warn_about_peers_once(node, guarded, callback_group, after_s: float = 3.0):
    """A timer that looks for peers every `after_s` after start, PEER_CHECKS times at most
    (discovery may not have seen them at the first look), and says so once."""
    looks = [0]

    def check():
        looks[0] += 1
        if warn_about_peers(node) or looks[0] >= PEER_CHECKS:
            timer.cancel()
    timer = node.create_timer(after_s, guarded(check), callback_group=callback_group)
    return timer


def warn_about_peers(node) -> bool:
    """Another global_loc server on this domain would execute every goal too (both publish
    poses): said, as an error; whether there is one."""
    peers = [ns for name, ns in node.get_node_names_and_namespaces() if name == node.get_name()]
    if len(peers) > 1:
        node.get_logger().error(f'{len(peers)} nodes named {node.get_name()} on this ROS domain: each executes '
                                f'every goal and publishes its poses; run one per domain or rename one')
    return len(peers) > 1


def wait_for_subscriber(publisher, stopping: threading.Event, timeout_s: float = 10.0, grace_s: float = 0.2) -> bool:
    """Until `publisher` has a subscriber, `timeout_s` passed or `stopping` is set; whether one
    came. A volatile message published before its subscriber matched is lost - AMCL's
    /initialpose from a start-up that answers from the first scan (AMCL started by the same
    launch subscribes within seconds). The grace gives the subscriber's side of the match a
    moment."""
    deadline = time.monotonic() + timeout_s
    while publisher.get_subscription_count() == 0:
        if stopping.wait(0.05) or time.monotonic() >= deadline:
            return False
    return not stopping.wait(grace_s)


def answer_every_change_state(node) -> None:
    """Make `node`'s (an rclpy LifecycleNode's) `~/change_state` answer `success=false` to
    a transition the current state does not have, as rclcpp nodes do. rclpy (Jazzy) checks
    a request by label but not by id: configure by id while active - what nav2's
    lifecycle_manager sends at start-up to a server already up with autostart - raises
    RCLError "Transition is not registered" into the executor and ends the process
    (ros2/rclpy#1209). A valid request runs rclpy's own handler unchanged."""
    service = node._service_change_state       # rclpy's: no public hook to wrap its callback
    handle = service.callback
    machine = node._state_machine

    def change_state(request, response):
        transition = request.transition
        available = {tid: label for tid, label, *_ in machine.available_transitions}
        state = machine.current_state[1]
        if not transition.label and transition.id not in available:
            node.get_logger().warn(f'change_state refused: transition id {transition.id} is not available in state '
                                   f'{state} (available: {", ".join(f"{i} {n}" for i, n in available.items())})')
            response.success = False
            return response
        try:
            return handle(request, response)
        except _rclpy.RCLError as e:     # a transition the state machine refused after all
            node.get_logger().warn(f'change_state refused in state {state}: {e}')
            response.success = False
            return response
    service.callback = change_state
