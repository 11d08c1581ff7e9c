"""A Python API for the global_loc server, modelled on nav2_simple_commander's BasicNavigator: a mission
script (or a test) asks where the robot is with one call and gets a typed answer, instead of starting
`test_global_loc` and parsing its JSON.

    rclpy.init()
    localizer = GlobalLocalizer()
    if not localizer.wait_until_active(30.0):
        raise SystemExit('no active global_loc server')
    result = localizer.localize(LocalizeGoal(resolve_by_motion_s=20.0, rotate_in_place=True))
    if result.success:
        print(result.pose, result.confidence)

Every call spins the localizer's own node (its own executor) until its answer, and ends: an answer the
server gave is a LocalizeResult (its `outcome` says how the goal ended); no server, a server that
disappears mid-goal, a goal request left unanswered or rejected is a GlobalLocError subclass - never a
hang. While `localize` runs, SIGINT (and whatever `cancel_signals` lists) cancels the goal, waits up to
CANCEL_WAIT_S for the server to accept the cancel, then raises KeyboardInterrupt: an interrupted script
leaves no goal turning the robot.
"""
from __future__ import annotations

import contextlib
import math
import signal
import threading
import time
from dataclasses import dataclass
from typing import Callable, Optional

from action_msgs.srv import CancelGoal
from lifecycle_msgs.srv import GetState
from rclpy.action import ActionClient
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import String
from std_srvs.srv import Trigger

from global_loc_interfaces.action import Localize

from .cancel_signals import signals_routed_to
from .localize_goal import LocalizeGoal  # noqa: F401  (the API's too)
from .localize_result import (  # noqa: F401  (the errors are the API's too)
    STATUS_NAMES,
    GlobalLocError,
    GoalRejected,
    GoalUnanswered,
    LocalizeResult,
    NoServer,
    ServerGone,
)

SERVER_GONE_S = 3.0    # the server absent from the ROS graph this long: it is gone (no answer will come)
STATE_CALL_S = 2.0     # wait_until_active: one ~/get_state call's answer, before it asks again
CANCEL_WAIT_S = 2.0    # an interrupted goal: how long to wait for the server to accept the cancel
GOAL_ANSWER_S = 2.0    # a spinning server answers a goal request in milliseconds: after this, was it lost?


@dataclass(frozen=True)
class ServerNames:
    """Which global_loc server a GlobalLocalizer talks to: its node (whose ~/get_state,
    ~/trigger and ~/status it uses) and its Localize action."""
    node: str = 'global_loc_server'
    action: str = 'localize'


class GlobalLocalizer(Node):
    """A client node of one global_loc server (`server`). `server_timeout_s` bounds every
    wait for the server to appear or to accept a request; `cancel_signals` cancel a running
    goal (localize)."""

    def __init__(self, node_name: str = 'global_localizer', namespace: str = '', *,
                 server: ServerNames = ServerNames(), server_timeout_s: float = 10.0,
                 cancel_signals: tuple = (signal.SIGINT,), context=None):
        super().__init__(node_name, namespace=namespace, context=context)
        self.server_node, self.action_name = server.node, server.action
        self.server_timeout_s, self.cancel_signals = server_timeout_s, cancel_signals
        self._action = ActionClient(self, Localize, server.action)
        self._get_state = self.create_client(GetState, f'{server.node}/get_state')
        self._trigger = self.create_client(Trigger, f'{server.node}/trigger')
        self._status: Optional[str] = None
        self.create_subscription(String, f'{server.node}/status', self._on_status, 10)
        self._executor = SingleThreadedExecutor(context=self.context)
        self._executor.add_node(self)
        self._running = False                       # a localize() call is under way
        self._cancel_wanted = threading.Event()     # cancel() or a signal asked to cancel it
        self._signalled = False                     # ... a signal did (KeyboardInterrupt after the cancel)

    def __enter__(self) -> 'GlobalLocalizer':
        return self

    def __exit__(self, *exc) -> None:
        self.destroy_node()

    def destroy_node(self) -> None:
        self._executor.remove_node(self)
        self._executor.shutdown(timeout_sec=1.0)
        self._action.destroy()
        super().destroy_node()

    # ---- the calls ---------------------------------------------------------------------------
    def wait_until_active(self, timeout_s: float) -> bool:
        """Whether, within `timeout_s`, the action server is up and the server node's
        lifecycle state (`~/get_state`) is `active`."""
        deadline = time.monotonic() + timeout_s
        if not self._action.wait_for_server(timeout_sec=max(0.0, timeout_s)):
            return False
        while time.monotonic() < deadline:
            if self._get_state.wait_for_service(timeout_sec=max(0.0, min(1.0, deadline - time.monotonic()))):
                with contextlib.suppress(ServerGone):    # a call lost in discovery is retried
                    if self._lifecycle_state(self._get_state.service_is_ready, deadline) == 'active':
                        return True
                self._spin_for(0.1)
        return False

    def localize(self, goal: Optional[LocalizeGoal] = None,
                 feedback: Optional[Callable[[Localize.Feedback], None]] = None) -> LocalizeResult:
        """One Localize goal, to its end: `goal`'s fields (None: the server's defaults for
        all); the result's `map` names the answer's map. `feedback(msg)` gets each
        Localize.Feedback (its `stage` is a core.outcome.Stage value). Raises TypeError for a
        `feedback` that is not callable (a goal's field of the wrong type already did, when
        the LocalizeGoal was made), NoServer, GoalUnanswered, GoalRejected, ServerGone;
        whatever else ends the call - KeyboardInterrupt, an exception `feedback` raised -
        cancels the goal first."""
        if feedback is not None and not callable(feedback):
            raise TypeError(f'feedback must be callable or None, got {type(feedback).__name__}')
        goal = LocalizeGoal() if goal is None else goal
        if not isinstance(goal, LocalizeGoal):
            raise TypeError(f'goal must be a LocalizeGoal or None, got {type(goal).__name__}')
        self._cancel_wanted.clear()
        self._signalled, self._running = False, True
        try:
            with signals_routed_to(self._on_signal, self.cancel_signals):
                response = self._run_goal(goal.to_msg(), feedback)
        finally:
            self._running = False
        return LocalizeResult.from_msg(response.result, response.status)

    def cancel(self) -> bool:
        """Cancel the running localize() (from another thread, or a feedback callback): it
        asks the server and returns the result the goal ends with. Whether one was running."""
        if self._running:
            self._cancel_wanted.set()
        return self._running

    def trigger(self) -> tuple[bool, str]:
        """`~/trigger` (std_srvs/Trigger): localize the next scan with the server's defaults;
        (success, the server's one-line message)."""
        if not self._trigger.wait_for_service(timeout_sec=self.server_timeout_s):
            raise NoServer(f'no service {self._trigger.srv_name} within {self.server_timeout_s:g} s')
        future = self._trigger.call_async(Trigger.Request())
        self._wait(future, self._trigger.service_is_ready)
        return bool(future.result().success), future.result().message

    def status(self, wait_s: float = 1.0) -> Optional[str]:
        """The newest `~/status` message (the server's health: 'localized fit=0.93', 'lost ...'),
        waiting up to `wait_s` for a first one; None when none came."""
        deadline = time.monotonic() + wait_s
        self._spin_for(0.0)
        while self._status is None and time.monotonic() < deadline:
            self._spin_for(0.05)
        return self._status

    # ---- the goal's steps --------------------------------------------------------------------
    def _run_goal(self, goal: Localize.Goal, feedback) -> object:
        """Send, wait for the result; cancel on request. The action's GetResult response."""
        if not self._action.wait_for_server(timeout_sec=self.server_timeout_s):
            raise NoServer(f'no global_loc server answered on action "{self.action_name}" within '
                           f'{self.server_timeout_s:g} s (is `ros2 run global_loc server` running, with the same '
                           f'ROS_DOMAIN_ID?)')
        if self._signalled:
            raise KeyboardInterrupt('before the goal was sent')
        served = self._action.server_is_ready
        handle = self._send_goal(goal, feedback, served)
        if handle is None or not handle.accepted:
            raise GoalRejected('the server rejected the goal')
        done = handle.get_result_async()
        cancel_sent = False
        try:
            done = self._wait_for_result(handle, done, served, self._cancel_wanted.is_set)
            if not done.done():
                cancel_sent = True
                accepted = self._request_cancel(handle, served)
                if self._signalled:
                    raise KeyboardInterrupt('the goal was canceled' if accepted else
                                            'the goal was not canceled: the server did not confirm the cancel')
                done = self._wait_for_result(handle, done, served)   # it ends canceled at the search's next step
        except BaseException:    # Ctrl-C, a feedback callback's exception, ServerGone: no goal left running
            if not cancel_sent:
                with contextlib.suppress(Exception):
                    self._request_cancel(handle, served)
            raise
        return done.result()

    def _send_goal(self, goal: Localize.Goal, feedback, served):
        """The goal's handle (accepted or not). Fast DDS drops the answer to a client the
        server has not matched yet (ros2/rmw_fastrtps#751: seen on a loaded CI machine right
        after discovery), and the server then never runs that goal. So a request still
        unanswered after GOAL_ANSWER_S while the server answers ~/get_state (it is spinning,
        not still starting) is sent again under a new goal id; should an earlier one be
        answered after all, the first answer is used and any other accepted goal canceled."""
        callback = (lambda m: feedback(m.feedback)) if feedback else None
        deadline = time.monotonic() + self.server_timeout_s
        sent = [self._action.send_goal_async(goal, feedback_callback=callback)]
        while not any(f.done() for f in sent):
            wait = min(GOAL_ANSWER_S, deadline - time.monotonic())
            if wait <= 0:
                raise GoalUnanswered(f'the global_loc server did not answer the goal request within '
                                     f'{self.server_timeout_s:g} s (it stopped, or it is still starting)')
            self._wait(sent[0], served, wait, stop=lambda: any(f.done() for f in sent))
            if not any(f.done() for f in sent) and self._lifecycle_state(served, deadline) is not None:
                self.get_logger().warn(f'no answer to the goal request within {GOAL_ANSWER_S:g} s while the server '
                                       f'answers ~/get_state: sending it again (lost in discovery)')
                sent.append(self._action.send_goal_async(goal, feedback_callback=callback))
        first = next(f for f in sent if f.done())
        for other in sent:
            if other is not first:
                other.add_done_callback(_cancel_if_accepted)
        return first.result()

    def _lifecycle_state(self, served, deadline: float) -> Optional[str]:
        """The server's lifecycle state from one ~/get_state call answered within
        STATE_CALL_S (and before `deadline`); None when the service is not there or the
        answer did not come."""
        if not self._get_state.service_is_ready():
            return None
        future = self._get_state.call_async(GetState.Request())
        self._wait(future, served, max(0.0, min(STATE_CALL_S, deadline - time.monotonic())))
        return future.result().current_state.label if future.done() and future.result() is not None else None

    def _wait_for_result(self, handle, done, served, stop: Callable[[], bool] = lambda: False):
        """Until the result comes or `stop()`; the result future. The result's answer can be
        lost as the goal's can: a goal the status topic says has ended without its result
        for GOAL_ANSWER_S is asked for its result again. (One wait per request: the
        server's absence is timed across it - ServerGone.)"""
        while True:
            lost = _EndedWithoutResult(handle)
            self._wait(done, served, stop=lambda lost=lost: stop() or lost())
            if done.done() or stop():
                return done
            self.get_logger().warn('the goal ended but its result did not come: asking again')
            done = handle.get_result_async()

    def _request_cancel(self, handle, served) -> bool:
        """Ask the server to cancel the goal; whether it accepted within CANCEL_WAIT_S."""
        future = handle.cancel_goal_async()
        try:
            self._wait(future, served, CANCEL_WAIT_S)
        except ServerGone:
            return False
        accepted = future.done() and future.result() is not None and \
            future.result().return_code == CancelGoal.Response.ERROR_NONE
        if not accepted:
            self.get_logger().warn(f'the server did not accept the cancel within {CANCEL_WAIT_S:g} s')
        return accepted

    def _wait(self, future, served: Callable[[], bool], limit_s: float = math.inf,
              stop: Callable[[], bool] = lambda: False) -> bool:
        """Spin until `future` is done (True), `limit_s` passed or `stop()` (False). Raises
        ServerGone when `served()` (the server on the graph) was false for SERVER_GONE_S."""
        deadline = time.monotonic() + limit_s
        absent_since = None
        while not future.done() and time.monotonic() < deadline and not stop():
            self._executor.spin_once(timeout_sec=0.05)
            if served():
                absent_since = None
            elif absent_since is None:
                absent_since = time.monotonic()
            elif time.monotonic() - absent_since > SERVER_GONE_S:
                raise ServerGone('the global_loc server disappeared before answering (crashed or stopped); '
                                 'no result')
        return future.done()

    def _spin_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        self._executor.spin_once(timeout_sec=0.0)
        while time.monotonic() < deadline:
            self._executor.spin_once(timeout_sec=max(0.0, min(0.05, deadline - time.monotonic())))

    def _on_status(self, msg: String) -> None:
        self._status = msg.data

    # ---- signals -----------------------------------------------------------------------------
    def _on_signal(self, signum, frame) -> None:
        """A cancel signal: the wait loop cancels the goal; a second one gives up waiting."""
        if self._signalled:
            raise KeyboardInterrupt(f'signal {signum}')
        self._signalled = True
        self._cancel_wanted.set()


def _cancel_if_accepted(future) -> None:
    """A goal request answered after another one was used: cancel it if it was accepted."""
    handle = future.result()
    if handle is not None and handle.accepted:
        handle.cancel_goal_async()


class _EndedWithoutResult:
    """Whether the status topic has said for GOAL_ANSWER_S that the goal ended (its result
    request then went unanswered)."""

    def __init__(self, handle):
        self.handle, self.ended_at = handle, None

    def __call__(self) -> bool:
        if self.handle.status not in STATUS_NAMES:
            return False
        self.ended_at = self.ended_at or time.monotonic()
        return time.monotonic() - self.ended_at > GOAL_ANSWER_S
