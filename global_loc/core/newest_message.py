"""NewestMessage: the newest message of a stream (scans, odometry) with its arrival time,
and a wait for one that arrives after a given moment. A subscription callback puts; a
goal's worker thread waits ("the first scan after the request") or asks whether any has
come (odometry). No ROS here, so the waiting rule (never a stale message, cancel seen
within `poll_s`) is tested without processes.
"""
from __future__ import annotations

import threading
import time
from typing import Callable, Generic, Optional, TypeVar

from .outcome import CanceledError

T = TypeVar('T')


class NewestMessage(Generic[T]):
    def __init__(self, clock: Callable[[], float] = time.monotonic):
        self._clock = clock
        self._cond = threading.Condition()
        self._latest: Optional[tuple[float, T]] = None    # (arrival time, message)

    def put(self, message: T) -> None:
        """Keep `message` as the newest one, arrived now."""
        with self._cond:
            self._latest = (self._clock(), message)
            self._cond.notify_all()

    def latest(self) -> Optional[T]:
        """The newest message, however old (None before the first)."""
        with self._cond:
            return None if self._latest is None else self._latest[1]

    def wait_after(self, since: float, timeout: float, cancelled: Callable[[], bool] = lambda: False,
                   poll_s: float = 0.05) -> Optional[T]:
        """The first message that arrived at or after `since` (a clock reading); None when
        none has by since + timeout; raises CanceledError as soon as `cancelled()` says so."""
        with self._cond:
            came = wait_on(self._cond, lambda: self._latest is not None and self._latest[0] >= since,
                           since + timeout, cancelled, self._clock, poll_s)
            return self._latest[1] if came else None


def wait_on(cond: threading.Condition, ready: Callable[[], bool], deadline: float, cancelled: Callable[[], bool],
            clock: Callable[[], float] = time.monotonic, poll_s: float = 0.05) -> bool:
    """With `cond` held: wait on it until `ready()` (True) or `clock()` passes `deadline`
    (False); raises CanceledError as soon as `cancelled()` says so (within poll_s). The
    one waiting rule of the streams a request waits on (NewestMessage, PoseHistory)."""
    while not ready():
        if cancelled():
            raise CanceledError()
        remaining = deadline - clock()
        if remaining <= 0:
            return False
        cond.wait(min(remaining, poll_s))
    return True
