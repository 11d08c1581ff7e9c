"""The server's waiting rule, without ROS: never a stale scan, a timeout, and a cancel
seen while waiting."""
import threading
import time

import pytest

from global_loc.core.newest_message import NewestMessage
from global_loc.core.outcome import CanceledError


def test_a_scan_from_before_the_goal_is_not_taken():
    waiter = NewestMessage()
    waiter.put('old')
    since = time.monotonic() + 1e-6
    assert waiter.wait_after(since, 0.2) is None          # timed out: 'old' arrived before
    threading.Timer(0.05, waiter.put, args=('fresh',)).start()
    assert waiter.wait_after(time.monotonic(), 5.0) == 'fresh'


def test_the_newest_scan_wins():
    waiter = NewestMessage()
    since = time.monotonic()
    waiter.put('first')
    waiter.put('second')
    assert waiter.wait_after(since, 1.0) == 'second'


def test_cancel_ends_the_wait_promptly():
    waiter = NewestMessage()
    cancel = threading.Event()
    threading.Timer(0.1, cancel.set).start()
    t0 = time.monotonic()
    with pytest.raises(CanceledError):
        waiter.wait_after(time.monotonic(), 60.0, cancel.is_set)
    assert time.monotonic() - t0 < 1.0
